"""Recording and replay as pure code: the file a killed recorder leaves, reading it back (ours
and the ``mcap`` library's linear reader), gaps by seq, and drag-teach on bad stamps."""

from __future__ import annotations

import io
import shutil
import time
from pathlib import Path

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from mcap.writer import Writer

from fleet.choreo.script import Move
from fleet.record.errors import RecordingUnreadable, TeachError
from fleet.record.gaps import SeqGaps
from fleet.record.reader import read_recording
from fleet.record.replay import MAX_TEACH_S, teach_script, usable_samples
from fleet.record.writer import RecordingWriter
from fleet.wire import keys
from fleet.wire import messages as m

SPACE = keys.KeySpace("lab")
JOINTS_KEY = SPACE.arm("a1", keys.JOINTS)
ZERO = (0.0,) * 7


def joints(seq: int, stamp_ns: int, angle: float = 0.0) -> m.Joints:
    return m.Joints(stamp_ns=stamp_ns, angles_deg=[angle] * 7, seq=seq)


def payload(seq: int) -> bytes:
    return msgspec.json.encode(joints(seq, 1_000_000_000 + seq * 100_000_000, seq * 0.1))


def write_flushed(path: Path, batches: int, per_batch: int) -> list[int]:
    """A recording of ``batches`` flushes; returns the file size after each flush (what a
    SIGKILL right then would leave)."""
    writer = RecordingWriter(path)
    sizes = []
    for b in range(batches):
        for i in range(per_batch):
            seq = b * per_batch + i
            writer.add(JOINTS_KEY, keys.JOINTS, payload(seq), 1000 + seq, seq)
        writer.flush()
        sizes.append(path.stat().st_size)
    shutil.copy(path, path.with_suffix(".killed"))  # the file as a SIGKILL now leaves it
    writer.finish()
    return sizes


# ---------------------------------------------------------------------- the file after a kill


def test_a_killed_recorder_leaves_every_flushed_message(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    write_flushed(path, batches=5, per_batch=10)
    killed = read_recording(path.with_suffix(".killed"))
    assert not killed.complete and killed.problem is not None
    assert len(killed.messages) == 50, killed.describe()
    assert "unfinished" in killed.describe() and "50 messages read" in killed.describe()
    assert [msgspec.json.decode(r.data)["seq"] for r in killed.messages] == list(range(50))
    finished = read_recording(path)
    assert finished.complete and finished.problem is None and len(finished.messages) == 50


def test_the_mcap_librarys_linear_reader_reads_a_killed_recording(tmp_path: Path) -> None:
    """The documented way to read an unfinished file with the ``mcap`` library alone: a
    NonSeekingReader in file order, stopping at the exception where the file ends."""
    path = tmp_path / "r.mcap"
    write_flushed(path, batches=3, per_batch=7)
    seen = []
    with open(path.with_suffix(".killed"), "rb") as stream:
        reader = NonSeekingReader(stream)
        with pytest.raises(McapError):  # EndOfFile: no footer
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                seen.append((channel.topic, message.data))
    assert len(seen) == 21 and seen[0] == (JOINTS_KEY, payload(0))


def test_a_file_cut_anywhere_reads_up_to_its_last_whole_chunk(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    sizes = write_flushed(path, batches=4, per_batch=5)
    data = path.read_bytes()
    header_end = 8 + 9 + len(b"d1-fleet") + 8  # magic, header record (empty profile)
    # Every cut is read; the ones at and around each flush (and the first and last) from a file
    # on disk, the others from memory by the same scan (writing ~2,900 files was most of the
    # time, and more than the test's whole budget on a loaded disk).
    on_disk = {header_end, len(data) - 1} | {s + d for s in sizes for d in (-1, 0, 1)}
    for cut in range(header_end, len(data)):
        if cut in on_disk:
            (tmp_path / "cut.mcap").write_bytes(data[:cut])
            recording = read_recording(tmp_path / "cut.mcap")
        else:
            recording = read_recording_stream(io.BytesIO(data[:cut]))
        whole_chunks = sum(1 for size in sizes if size <= cut)
        assert len(recording.messages) >= 5 * whole_chunks, (cut, recording.describe())
        assert recording.complete == (cut == len(data))


def test_old_finished_recordings_still_read(tmp_path: Path) -> None:
    """A file written like before (1 MiB chunks, finished): indexed, complete."""
    path = tmp_path / "old.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="d1-fleet")
        schema = writer.register_schema(name="Joints", encoding="jsonschema", data=b"{}")
        channel = writer.register_channel(JOINTS_KEY, "json", schema)
        for seq in range(30):
            writer.add_message(channel, log_time=30 - seq, data=payload(seq), publish_time=0)
        writer.finish()
    recording = read_recording(path)
    assert recording.complete and len(recording.messages) == 30
    assert [r.log_time_ns for r in recording.messages] == list(range(1, 31))  # log-time order


@pytest.mark.parametrize("content", [b"", b"\x89MCAP0\r", b"not an mcap file at all", b"\0" * 64])
def test_not_a_recording_is_a_clear_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    with pytest.raises(RecordingUnreadable, match=f"^{path}: not an MCAP recording"):
        read_recording(path)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    cut=st.integers(min_value=0, max_value=4000),
    flips=st.lists(st.tuples(st.integers(0, 4000), st.integers(0, 255)), max_size=4),
)
def test_damaged_files_give_a_recording_or_the_documented_error(
    cut: int, flips: list[tuple[int, int]]
) -> None:
    data = bytearray(DAMAGE_BASE)
    for where, value in flips:
        data[where % len(data)] = value
    stream = io.BytesIO(bytes(data[: len(data) - cut % len(data)]))
    try:
        recording = read_recording_stream(stream)
    except RecordingUnreadable:
        return
    originals = {(JOINTS_KEY, payload(seq)) for seq in range(40)}
    assert {(r.key, r.data) for r in recording.messages} <= originals


def _damage_base() -> bytes:
    stream = io.BytesIO()
    writer = Writer(stream, chunk_size=64 * 1024)
    writer.start(profile="", library="d1-fleet")
    schema = writer.register_schema(name="Joints", encoding="jsonschema", data=b"{}")
    channel = writer.register_channel(JOINTS_KEY, "json", schema)
    for seq in range(40):
        writer.add_message(channel, log_time=seq, data=payload(seq), publish_time=seq)
        if seq % 10 == 9:
            writer.flush()
    writer.finish()
    return stream.getvalue()


DAMAGE_BASE = _damage_base()


def read_recording_stream(stream: io.BytesIO):  # type: ignore[no-untyped-def]
    from fleet.record.reader import _scan

    return _scan(stream, "x.mcap", len(stream.getvalue()))


# ---------------------------------------------------------------------- gaps by seq


def test_gaps_by_seq_per_arm() -> None:
    gaps = SeqGaps()
    for seq in [5, 6, 7, 10, 11, 15]:  # the recording starts at 5: nothing missing before
        gaps.add("a1", seq)
    for seq in [1, 2, 3, 1, 2]:  # an agent restart
        gaps.add("a2", seq)
    assert gaps.missing() == {"a1": 5, "a2": 0}
    assert gaps.arms["a1"].holes == 2 and gaps.arms["a2"].restarts == 1
    assert "6 received, 5 missing (45.5 %) in 2 holes" in gaps.describe()


# ---------------------------------------------------------------------- drag-teach


def test_teach_skips_out_of_order_stamps() -> None:
    t = 1_000_000_000_000
    samples = [joints(i, t + i * 100_000_000, i * 0.5) for i in range(20)]
    samples[5] = joints(5, t - 50_000_000_000)  # 50 s back: a stray sample
    samples[12] = joints(12, samples[11].stamp_ns)  # a repeated stamp
    kept, skipped = usable_samples(samples)
    assert skipped == 2 and len(kept) == 18
    script = teach_script(samples, "a2", ZERO, "rec.mcap")
    moves = [s for s in script.steps if isinstance(s, Move)]
    assert len(moves) == 1 + 19  # the approach, then 1.9 s at 10 Hz
    assert moves[-1].poses["a2"] == pytest.approx((9.5,) * 7)


def test_teach_refuses_a_recording_too_long_to_replay() -> None:
    t = 1_000_000_000_000
    long_take = [joints(1, t), joints(2, t + int(10 * MAX_TEACH_S * 1e9))]
    with pytest.raises(TeachError, match=r"^rec.mcap: the joint samples span 36000 s"):
        teach_script(long_take, "a2", ZERO, "rec.mcap")
    started = time.monotonic()
    with pytest.raises(TeachError, match="at most 3600 s"):
        teach_script([joints(1, 0), joints(2, 2**63 - 1)], "a2", ZERO, "rec.mcap")
    assert time.monotonic() - started < 1.0
    with pytest.raises(TeachError, match="fewer than two usable"):
        teach_script([joints(1, t), joints(2, t)], "a2", ZERO, "rec.mcap")
