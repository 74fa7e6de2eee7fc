"""Issue 28, finding 2: no file a running process reads can freeze its safety or relay path.
Bounded reads (regular files only, size caps), validated calibrations, the watcher's stuck
detection with an injected clock, and a real agent whose calibration file became a named pipe."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import msgspec
import pytest

from fleet.contact.calibration import (
    Calibration,
    CalibrationError,
    JointCalibration,
    load_calibration,
    save_calibration,
)
from fleet.contact.dynamics import ModeDynamics
from fleet.files import FileReadError, FileWatcher, read_regular
from testkit.harness import FleetHarness, next_diag, wait_until


def _in_thread(fn, timeout_s: float = 3.0) -> object:  # type: ignore[no-untyped-def]
    """``fn()`` on a daemon thread; fails if it does not return within ``timeout_s``."""
    out: list[object] = []
    thread = threading.Thread(target=lambda: out.append(_capture(fn)), daemon=True)
    thread.start()
    thread.join(timeout_s)
    assert not thread.is_alive(), "the read blocked"
    return out[0]


def _capture(fn):  # type: ignore[no-untyped-def]
    try:
        return fn()
    except (FileReadError, CalibrationError) as exc:
        return exc


def test_a_named_pipe_is_refused_at_once(tmp_path: Path) -> None:
    fifo = tmp_path / "a1.json"
    os.mkfifo(fifo)
    result = _in_thread(lambda: read_regular(fifo))
    assert isinstance(result, FileReadError) and "not a regular file" in str(result)
    result = _in_thread(lambda: load_calibration(fifo))
    assert isinstance(result, CalibrationError) and str(fifo) in str(result)


def test_a_big_file_is_refused_and_a_small_one_read(tmp_path: Path) -> None:
    big = tmp_path / "big"
    big.write_bytes(b"x" * 2048)
    with pytest.raises(FileReadError, match="more than 1024"):
        read_regular(big, max_bytes=1024)
    assert read_regular(big, max_bytes=4096) == b"x" * 2048
    with pytest.raises(FileNotFoundError):
        read_regular(tmp_path / "absent")


def _calibration(**joint: object) -> Calibration:
    mode = ModeDynamics(rate_deg_s=60.0, lag_s=0.1)
    fields = {"joint": 0, "mode0": mode, "mode1": mode, "rms_deg": 0.5, **joint}
    return Calibration(arm="a1", stamp_ns=1, joints=[JointCalibration(**fields)])  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "joint", [{"rms_deg": 1e300}, {"rms_deg": -1.0}, {"timing_rms_deg": 1e9}, {"joint": 9}]
)
def test_implausible_calibrations_are_refused(tmp_path: Path, joint: dict[str, object]) -> None:
    path = tmp_path / "a1.json"
    save_calibration(path, _calibration(**joint))
    with pytest.raises(CalibrationError, match="a1.json"):
        load_calibration(path)


def test_infinity_in_a_calibration_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "a1.json"
    data = json.loads(msgspec.json.encode(_calibration()))
    data["feedback_jitter_s"] = 1e999  # parsed as inf
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationError):
        load_calibration(path)
    save_calibration(path, _calibration())
    assert load_calibration(path) is not None


def test_the_watcher_says_how_long_a_read_is_stuck() -> None:
    now = [100.0]
    release, stopping = threading.Event(), threading.Event()

    def poll() -> str:
        release.wait(5.0)
        return "read"

    watcher = FileWatcher(poll, 0.01, stopping, clock=lambda: now[0])
    thread = threading.Thread(target=watcher.run, daemon=True)
    thread.start()
    wait_until(lambda: watcher.stuck_s(107.0) == pytest.approx(7.0), 2.0)  # reading since 100
    release.set()
    wait_until(lambda: watcher.take() == "read", 2.0)
    stopping.set()
    thread.join(2.0)
    assert watcher.stuck_s() == 0.0


def test_a_calibration_pipe_does_not_freeze_the_agent(fleet_harness: FleetHarness) -> None:
    h = fleet_harness
    client = h.start_fleet()
    path = h.tmp_path / "calibration" / "a1.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    # the agent re-reads the calibration every second: its diag names the refusal, and its
    # feedback relay goes on (joints keep coming for the next 3 s)
    wait_until(
        lambda: "not a regular file" in (next_diag(client, "test", "a1").contact_model or ""),
        10.0,
    )
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline:
        _status, joints = client.snapshot(wait_s=0.5)["a1"]
        assert joints is not None, h.diagnose(client)
    acks = client.estop(timeout_s=3.0)
    assert acks["a1"] is not None and acks["a1"].done, h.diagnose(client)
    assert h.processes["agent"].poll() is None


def test_an_inventory_pipe_is_refused_at_once(tmp_path: Path) -> None:
    from fleet.inventory import InventoryError, load_inventory

    fifo = tmp_path / "inventory.toml"
    os.mkfifo(fifo)
    result = _in_thread(lambda: _raises(lambda: load_inventory(fifo), InventoryError))
    assert "not a regular file" in str(result)


def _raises(fn, kind):  # type: ignore[no-untyped-def]
    try:
        fn()
    except kind as exc:
        return exc
    raise AssertionError("accepted")
