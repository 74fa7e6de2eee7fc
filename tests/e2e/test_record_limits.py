"""Hostile recordings (issue 28, item 4): small files crafted to expand hugely are refused with one
line naming the file, in bounded memory; ``fleet replay`` and ``fleet viewer --replay`` exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Schema
from mcap.writer import MCAP0_MAGIC

from fleet.record.errors import RecordingTooLarge, RecordingUnreadable
from fleet.record.reader import MIN_DECOMPRESSED_BYTES, ReadLimits, read_recording
from fleet.wire import keys

KEY = keys.KeySpace("lab").arm("a1", keys.JOINTS)
MESSAGE = b'{"stamp_ns":1,"angles_deg":[0,0,0,0,0,0,0],"seq":1}'
ROOT = Path(__file__).resolve().parents[2]


def _records(*records: object) -> bytes:
    builder = RecordBuilder()
    for record in records:
        record.write(builder)  # type: ignore[attr-defined]
    return bytes(builder.end())


def message_records(count: int, data: bytes = MESSAGE) -> bytes:
    """``count`` message records on channel 1, as they sit inside a chunk."""
    return _records(Message(1, log_time=1, data=data, publish_time=1, sequence=0)) * count


def crafted(path: Path, block: bytes, repeats: int) -> int:
    """An MCAP file with one zstd chunk of ``block`` repeated ``repeats`` times (its declared
    size is the true one); returns the file's size."""
    compressor = zstandard.ZstdCompressor(level=3).compressobj(size=len(block) * repeats)
    parts = [compressor.compress(block) for _ in range(repeats)]
    data = b"".join(parts) + compressor.flush()
    chunk = Chunk(
        compression="zstd",
        data=data,
        message_end_time=1,
        message_start_time=1,
        uncompressed_crc=0,
        uncompressed_size=len(block) * repeats,
    )
    body = _records(
        Header(profile="", library="hostile"),
        Schema(id=1, name="Joints", encoding="jsonschema", data=b"{}"),
        Channel(id=1, topic=KEY, message_encoding="json", schema_id=1, metadata={}),
        chunk,
        DataEnd(0),
        Footer(0, 0, 0),
    )
    path.write_bytes(MCAP0_MAGIC + body + MCAP0_MAGIC)
    return path.stat().st_size


def read_in_child(path: Path, address_space_bytes: int = 1 << 30) -> dict[str, object]:
    """``read_recording(path)`` in a child whose address space is capped (a blow-up fails
    there, not on the test host): what it raised, its message and its peak RSS."""
    code = f"""
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({address_space_bytes}, {address_space_bytes}))
from fleet.record.reader import read_recording
try:
    recording = read_recording(sys.argv[1])
    out = {{"error": None, "messages": len(recording.messages)}}
except BaseException as exc:
    out = {{"error": type(exc).__name__, "message": str(exc)}}
# The peak of this process's own memory since exec (ru_maxrss keeps the forking parent's).
status = open("/proc/self/status").read().split("VmHWM:")[1]
out["max_rss_kb"] = int(status.split()[0])
print(json.dumps(out))
"""
    run = subprocess.run(
        [sys.executable, "-c", code, str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def test_a_small_file_expanding_to_a_gibibyte_is_refused_in_bounded_memory(tmp_path: Path) -> None:
    path = tmp_path / "bomb.mcap"
    block = message_records(12_000)  # ~1 MiB of real message records
    size = crafted(path, block, 1024)  # ~1 GiB decompressed
    assert size < 1_000_000
    out = read_in_child(path)
    assert out["error"] == "RecordingTooLarge", out
    message = str(out["message"])
    assert message.startswith(f"{path}: refused: ") and "\n" not in message
    assert int(out["max_rss_kb"]) < 400_000, out  # measured: ~150 MB


def test_a_small_file_of_millions_of_messages_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "many.mcap"
    size = crafted(path, message_records(10_000, b""), 100)  # a million empty messages
    assert size < 1_000_000
    with pytest.raises(RecordingTooLarge, match=f"^{path}: refused: more than 200000 messages"):
        read_recording(path)


def test_one_huge_message_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "huge.mcap"
    crafted(path, message_records(1, b"0" * (5 << 20)), 1)
    with pytest.raises(RecordingTooLarge, match="a message of 5242880 bytes, more than"):
        read_recording(path)


def test_limits_scale_with_the_file_within_bounds() -> None:
    small, big = ReadLimits.for_size(10_000), ReadLimits.for_size(100 << 20)
    assert small.decompressed_bytes == MIN_DECOMPRESSED_BYTES and small.messages == 200_000
    assert big.decompressed_bytes == 4 << 30 and big.messages == 20_000_000


def test_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    path = tmp_path / "pipe.mcap"
    os.mkfifo(path)
    with pytest.raises(RecordingUnreadable, match="not a regular file"):
        read_recording(path)


@pytest.mark.parametrize("command", [["replay"], ["viewer", "--replay"]])
def test_the_cli_refuses_a_bomb_in_one_line(tmp_path: Path, command: list[str]) -> None:
    path = tmp_path / "bomb.mcap"
    crafted(path, message_records(10_000, b""), 100)
    run = subprocess.run(
        [sys.executable, "-m", "fleet.cli.main", *command, str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "refused" in lines[0], run.stderr
