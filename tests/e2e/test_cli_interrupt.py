"""Ctrl-C on a command that moves an arm: ``fleet move --wait`` and ``fleet calibrate`` hold
the arm they moved where it stands, say so, and exit 130. Before: both exited 0 without a
word, and the arm went on to the target (calibrate: on to the end of its step)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from fleet.client import FleetClient
from testkit.harness import FleetHarness, wait_until

SLOW_ARM = "[arms.a1.sim_dynamics]\nmode1 = {rate_deg_s = 15.0, lag_s = 0.1}\n"
"""15 deg/s in mode 1 (the move's and the calibration steps'): a move of 90 deg lasts 6 s."""


@pytest.fixture
def slow_fleet(tmp_path: Path) -> Iterator[tuple[FleetHarness, FleetClient]]:
    with FleetHarness(tmp_path, arms=1, extra=SLOW_ARM) as harness:
        yield harness, harness.start_fleet()


def _joint0(client: FleetClient) -> float | None:
    _status, joints = client.snapshot(["a1"], wait_s=0.5).get("a1", (None, None))
    return None if joints is None else joints.angles_deg[0]


def _still_at(client: FleetClient) -> float | None:
    """Joint 0's angle once two readings 0.5 s apart agree within 0.3 deg, else None."""
    first = _joint0(client)
    time.sleep(0.5)  # pacing: the window over which a held arm must not move
    second = _joint0(client)
    if first is None or second is None or abs(second - first) > 0.3:
        return None
    return second


def _fleet(harness: FleetHarness, argv: list[str]) -> subprocess.Popen[str]:
    """``fleet ARGV`` on the harness's inventory, as a child process, its output piped."""
    return subprocess.Popen(
        [sys.executable, "-m", "fleet.cli.main", *argv, "--inventory", str(harness.inventory_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def _ctrl_c_once_moving(
    harness: FleetHarness, client: FleetClient, argv: list[str], beyond_deg: float
) -> tuple[int, str, float]:
    """Run ``fleet ARGV`` on the harness's inventory, Ctrl-C it once joint 0 passed
    ``beyond_deg``; (exit code, its output, joint 0 when the signal went)."""
    process = _fleet(harness, argv)
    try:
        at = wait_until(
            lambda: (angle := _joint0(client)) is not None and angle > beyond_deg and angle,
            30.0,
        )
        process.send_signal(signal.SIGINT)
        out, _ = process.communicate(timeout=15)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=5)
    return process.returncode, out, at


def test_ctrl_c_on_a_waited_move_holds_the_arm_and_exits_130(
    slow_fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = slow_fleet
    argv = ["move", "a1", "--joint", "0", "--angle", "90", "--wait", "--timeout", "20"]
    code, out, at = _ctrl_c_once_moving(harness, client, argv, beyond_deg=10.0)
    print(out)
    assert code == 130, out
    assert "fleet move: interrupted; holding a1" in out and "a1: held" in out, out
    held = wait_until(lambda: _still_at(client), 10.0)
    print(f"interrupted at {at:.1f} deg, held at {held:.1f} deg (the move's target: 90)")
    assert held < 45.0, (at, held, out)  # it went on to 90 deg before
    status, _joints = client.snapshot(["a1"])["a1"]
    assert status is not None and not status.estopped, status  # a hold, not a latched stop


def test_ctrl_c_on_calibrate_holds_the_arm_writes_nothing_and_exits_130(
    slow_fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = slow_fleet
    calibration = harness.inventory.calibration_path("a1")
    code, out, at = _ctrl_c_once_moving(
        harness, client, ["calibrate", "a1", "--joint", "0"], beyond_deg=15.0
    )
    assert code == 130, out
    assert "fleet calibrate: interrupted; holding a1" in out and "a1: held" in out, out
    assert "nothing was written" in out, out
    assert not Path(calibration).exists()
    held = wait_until(lambda: _still_at(client), 10.0)
    # Its steps: 10 deg, back to 0, 40 deg: 15 deg is passed on the way to 40.
    print(f"interrupted at {at:.1f} deg, held at {held:.1f} deg (the step's target: 40)")
    assert held < 32.0, (at, held, out)


def test_ctrl_c_with_a_silent_agent_says_the_arm_was_not_stopped(
    slow_fleet: tuple[FleetHarness, FleetClient],
) -> None:
    """The agent freezes mid-move: the hold gets no answer, nor does the protective stop sent
    instead; the command says so (use the hardware stop) and still exits 130, within its
    bound."""
    harness, client = slow_fleet
    agent = harness.processes["agent"]
    argv = ["move", "a1", "--joint", "0", "--angle", "90", "--wait", "--timeout", "20"]
    process = _fleet(harness, argv)
    try:
        wait_until(lambda: (angle := _joint0(client)) is not None and angle > 5.0, 30.0)
        os.kill(agent.pid, signal.SIGSTOP)
        started = time.monotonic()
        process.send_signal(signal.SIGINT)
        out, _ = process.communicate(timeout=20)
        took_s = time.monotonic() - started
    finally:
        os.kill(agent.pid, signal.SIGCONT)
        if process.poll() is None:
            process.kill()
            process.wait(timeout=5)
    print(out, f"exited {took_s:.1f} s after the Ctrl-C")
    assert process.returncode == 130, out
    assert "a1: NOT stopped: its hold failed" in out and "hardware stop" in out, out
    assert took_s < 12.0, out
