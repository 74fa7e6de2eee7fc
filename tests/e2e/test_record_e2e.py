"""``fleet record`` as a process on a real router (and, for the kill test, a real simulator and
agent): a SIGKILL leaves a readable file, bad samples are skipped and counted, gaps by seq are
reported, a recorder whose file cannot grow exits 1 with the reason. ``fleet replay`` reads the
unfinished file and refuses what is not a recording with exit 2.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest
import zenoh
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader

from fleet.record.reader import read_recording
from fleet.record.recorder import RECORDED_CHANNELS
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.harness import FleetHarness, wait_until

FLEET_CLI = ("-m", "fleet.cli.main")


def _exited(h: FleetHarness, name: str, timeout_s: float) -> int:
    process = h.processes[name]
    wait_until(lambda: process.poll() is not None, timeout_s)
    return int(process.returncode)


def _start_record(h: FleetHarness, path: Path, *extra: str, prefix: tuple[str, ...] = ()) -> None:
    h.start("record", [*FLEET_CLI, "record", "-o", str(path), *extra], prefix=prefix)
    wait_until(lambda: "recording " in h.log("record") or h.processes["record"].poll(), 15.0)
    assert h.processes["record"].poll() is None, h.log("record")


def test_a_sigkilled_recording_is_readable_up_to_the_last_flush(
    fleet_harness: FleetHarness, tmp_path: Path
) -> None:
    h = fleet_harness
    h.start_fleet()
    path = tmp_path / "killed.mcap"
    _start_record(h, path, "--arm", "a1")
    time.sleep(3.0)  # the recording window itself (the arm publishes joints at ~10 Hz)
    kill_ns = time.time_ns()
    h.processes["record"].send_signal(signal.SIGKILL)
    h.processes["record"].wait(timeout=5.0)

    recording = read_recording(path)
    assert not recording.complete and "unfinished" in recording.describe(), recording.describe()
    joints_key = keys.KeySpace(h.inventory.fleet).arm("a1", keys.JOINTS)
    joints = [
        (r.log_time_ns, payloads.JOINTS.decode(r.data))
        for r in recording.messages
        if r.key == joints_key
    ]
    assert len(joints) >= 15, recording.describe()  # 3 s at ~10 Hz, less at most 1 s
    lost_s = (kill_ns - joints[-1][0]) / 1e9
    print(f"{len(joints)} joints kept; the last one {lost_s:.2f} s before the SIGKILL")
    assert lost_s < 1.0, f"the last {lost_s:.2f} s before the kill are lost"
    seqs = [j.seq for _t, j in joints]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a joints sample is missing"

    # The mcap library alone, read linearly (the README's recipe), finds the same messages.
    with open(path, "rb") as stream:
        found = []
        with pytest.raises(McapError):
            for _s, channel, message in NonSeekingReader(stream).iter_messages(
                log_time_order=False
            ):
                found.append((channel.topic, message.data))
    assert sorted(found) == sorted((r.key, r.data) for r in recording.messages)

    # `fleet replay` replays what is there and says the file is unfinished.
    h.start("replay", [*FLEET_CLI, "replay", str(path), "--speed", "10"])
    assert _exited(h, "replay", 20.0) == 0, h.log("replay")
    assert "unfinished" in h.log("replay") and "published " in h.log("replay"), h.log("replay")
    assert "Traceback" not in h.log("replay")


def test_bad_samples_are_skipped_and_gaps_by_seq_reported(
    fleet_harness: FleetHarness, tmp_path: Path
) -> None:
    """Only a router: the test publishes a1's joints itself, with holes in seq, bad payloads
    and wildcard puts in between (any Zenoh client can)."""
    h = fleet_harness
    h.start_router()
    client = h.client()
    path = tmp_path / "bad.mcap"
    _start_record(h, path, "--arm", "a1")
    space = client.keys
    session: zenoh.Session = client.session
    joints_pub = session.declare_publisher(space.arm("a1", keys.JOINTS))
    wait_until(lambda: joints_pub.matching_status.matching, 10.0)
    sent = [seq for seq in range(1, 41) if seq not in (11, 12, 13, 30)]
    bad = 0
    for seq in sent:
        joints_pub.put(msgspec.json.encode(m.Joints(time.time_ns(), [float(seq)] * 7, seq)))
        if seq in (5, 20, 35):  # a bad sample of every kind, three times over
            joints_pub.put(b"{not json")
            session.put(space.arm("a1", keys.STATUS), b'{"stamp_ns": -1, "link": "ok"}')
            session.put(f"fleet/{space.fleet}/**", b"{}")
            session.put(f"fleet/{space.fleet}/arm/*/joints", b"{}")
            # `**` reaches every subscription: the arm's channels, the fleet's estop and reset
            bad += 2 + (len(RECORDED_CHANNELS) + 2) + 1
        time.sleep(0.01)  # 100 Hz, like a fast arm
    # Every good sample is in the file (flushed within 0.5 s; read while it is being written).
    joints_key = space.arm("a1", keys.JOINTS)

    def recorded_joints() -> list[bytes]:  # (the file also holds the derived 3D channels)
        return [r.data for r in read_recording(path).messages if r.key == joints_key]

    wait_until(lambda: len(recorded_joints()) == len(sent), 5.0)
    assert h.stop("record", sig=signal.SIGINT) == 0, h.log("record")
    out = h.log("record")
    assert "(finished)" in out and f"{bad} bad samples skipped" in out, out
    assert f"a1: {len(sent)} received, 4 missing" in out and "in 2 holes" in out, out
    assert "0 dropped" in out, out

    recording = read_recording(path)
    assert recording.complete
    seqs = [payloads.JOINTS.decode(data).seq for data in recorded_joints()]  # all valid
    assert seqs == sent, "the recording stopped or kept a bad sample"


def test_a_recorder_whose_file_cannot_grow_exits_1_with_the_reason(
    fleet_harness: FleetHarness, tmp_path: Path
) -> None:
    """RLIMIT_FSIZE plays a full disk: the recorder thread's flush fails with EFBIG once the
    file reaches 32 KiB (Zenoh's shared-memory segment, created under the same limit, needs
    less than 16 KiB)."""
    h = fleet_harness
    h.start_router()
    client = h.client()
    path = tmp_path / "full.mcap"
    limit = (
        sys.executable,
        "-c",
        "import os, resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, (32768, 32768)); "
        "os.execv(sys.argv[1], sys.argv[1:])",
    )
    _start_record(h, path, "--arm", "a1", prefix=limit)
    pub = client.session.declare_publisher(client.keys.arm("a1", keys.JOINTS))
    wait_until(lambda: pub.matching_status.matching, 10.0)
    started = time.monotonic()
    seq = 0
    while h.processes["record"].poll() is None and time.monotonic() - started < 15.0:
        seq += 1
        pub.put(msgspec.json.encode(m.Joints(time.time_ns(), [seq * 1e-3] * 7, seq)))
        time.sleep(0.002)  # ~500 Hz: the file grows by ~10 KiB per flush
    code = _exited(h, "record", 5.0)
    out = h.log("record")
    assert code == 1, out
    assert "fleet record: the recorder failed (OSError: [Errno 27] File too large)" in out, out
    assert "is unfinished, readable up to its last flush" in out, out
    recording = read_recording(path)  # what was flushed before the limit
    assert recording.messages and not recording.complete, recording.describe()
    print(recording.describe())
    print(f"the recorder failed and exited {time.monotonic() - started:.1f} s after the start")


def test_replay_refuses_what_is_not_a_recording(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    replay = subprocess.run(
        [sys.executable, *FLEET_CLI, "replay", str(empty), "--inventory", "inventory.toml"],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=Path(__file__).resolve().parents[2],
    )
    assert replay.returncode == 2, replay
    assert f"{empty}: not an MCAP recording (0 bytes" in replay.stderr
    assert "Traceback" not in replay.stderr
