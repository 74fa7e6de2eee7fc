"""Issue 13 end to end (real DDS, Zenoh, agent, simulator): arms whose dynamics differ from the
detector's assumptions (constant 60 deg/s, a slow lag with dead time, a second-order servo that
overshoots, with 8-12 Hz feedback) move freely to the spec's example pose and to every joint
limit with no contact and no refusal; a real wall is still found and force-limited; ``fleet
calibrate`` recovers the simulated constants within 10 % and the arm's status says so."""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest

from fleet.client import FleetClient
from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.harness import FleetHarness, next_diag, wait_until
from testkit.load import xfail_if_overloaded

DYNAMICS = """
[arms.a1.sim_dynamics]
mode0 = {rate_deg_s = 60.0, lag_s = 0.0}
mode1 = {rate_deg_s = 60.0, lag_s = 0.0}

[arms.a2.sim_dynamics]
mode0 = {rate_deg_s = 60.0, lag_s = 0.4, dead_s = 0.05}
mode1 = {rate_deg_s = 45.0, lag_s = 0.5, dead_s = 0.08}

[arms.a3.sim_dynamics]
mode0 = {rate_deg_s = 120.0, lag_s = 0.03, servo_hz = 2.5, overshoot = 0.1}
mode1 = {rate_deg_s = 90.0, lag_s = 0.1, servo_hz = 1.5, overshoot = 0.1}
feedback_hz = [8.0, 12.0]
jitter_s = 0.03
"""
SPEC_POSE = [0.0, -60.0, 60.0, 0.0, 30.0, 0.0, 0.0]
UPPER = [hi for _lo, hi in JOINT_RANGE_DEG]
LOWER = [lo for lo, _hi in JOINT_RANGE_DEG]


@pytest.fixture
def harness(tmp_path: Path) -> Any:
    with FleetHarness(tmp_path, arms=3, extra=DYNAMICS) as h:
        yield h


def _events(
    client: FleetClient, arms: list[str]
) -> tuple[list[Any], dict[str, list[m.ContactEvent]]]:
    events: dict[str, list[m.ContactEvent]] = {arm: [] for arm in arms}
    subs = [
        client.session.declare_subscriber(
            client.keys.arm(arm, keys.CONTACT),
            lambda s, arm=arm: events[arm].append(payloads.CONTACT.decode(s.payload.to_bytes())),
        )
        for arm in arms
    ]
    return subs, events


def _alarms(events: dict[str, list[m.ContactEvent]]) -> list[m.ContactEvent]:
    return [e for es in events.values() for e in es if e.state == "confirmed" or e.force_limited]


def _moves(client: FleetClient, arm: str) -> list[m.CommandReply]:
    replies = []
    for pose, mode in ((SPEC_POSE, 1), (UPPER, 1), (LOWER, 0), (SPEC_POSE, 0), ([0.0] * 7, 1)):
        move = m.MoveJoints(angles_deg=pose, mode=mode, wait_reached=True, timeout_s=15.0)
        replies.append(client.command(arm, move))
    return replies


@pytest.mark.timing
def test_unlike_arms_move_freely_and_calibration_recovers_their_constants(
    harness: FleetHarness,
) -> None:
    h = harness
    client = h.start_fleet()
    arms = ["a1", "a2", "a3"]
    status = client.snapshot()
    assert all(status[a][0] is not None for a in arms)
    wait_until(
        lambda: all(
            (s := client.snapshot()[a][0]) is not None and s.contact_model == "uncalibrated"
            for a in arms
        ),
        5.0,
    )
    subs, events = _events(client, arms)
    with ThreadPoolExecutor(max_workers=3) as pool:
        results = dict(zip(arms, pool.map(lambda a: _moves(client, a), arms), strict=True))
    for arm, replies in results.items():
        for reply in replies:
            assert reply.ok and reply.reached, (arm, reply)
    assert _alarms(events) == []

    calibrate = h.start("calibrate", ["-m", "fleet.cli.main", "calibrate", "a1", "--joint", "0"])
    wait_until(lambda: calibrate.poll() is not None, 90.0, interval_s=0.5)
    assert calibrate.returncode == 0, h.log("calibrate")
    saved = json.loads((h.tmp_path / "calibration" / "a1.json").read_text())
    (joint,) = saved["joints"]
    # a1 has no lag: what is fitted is the timing noise of 10 Hz reports on a shared host
    # (0.036-0.040 s at load 5-10, 0.0525 at load 8-14), bounded by half a report period; a2's
    # lag is 0.4 s. Checked last (testkit/load.py).
    noisy = [
        f"{mode} {what} {joint[mode][what]:.4f} s"
        for mode in ("mode0", "mode1")
        for what in ("lag_s", "dead_s")
        if joint[mode][what] >= 0.05
    ]
    for mode in ("mode0", "mode1"):
        assert joint[mode]["rate_deg_s"] == pytest.approx(60.0, rel=0.1), h.log("calibrate")
    # Joint 0 only: the model is partial, never "calibrated" (it read calibrated, issue 26),
    # and the agent's diag names the joints that are not.
    wait_until(lambda: client.snapshot()["a1"][0].contact_model == "partial", 5.0)
    note = next_diag(client, h.inventory.fleet, "a1").contact_model or ""
    assert "joints j1 j2 j3 j4 j5 j6 not calibrated" in note, note
    assert _alarms(events) == []
    for sub in subs:
        sub.undeclare()
    xfail_if_overloaded(noisy)
    assert not noisy, noisy


def test_a_wall_is_found_and_force_limited_on_an_unlike_arm(harness: FleetHarness) -> None:
    h = harness
    client = h.start_fleet()
    subs, events = _events(client, ["a1", "a3"])
    for arm in ("a1", "a3"):
        fault = b'{"op": "obstacle", "joint": 1, "angle_deg": 15.0, "compliance": 0.05}'
        key = client.keys.arm(arm, keys.SIM_FAULT)
        assert any(r.ok is not None for r in client.session.get(key, payload=fault, timeout=5))
    started = time.monotonic()
    move = m.MoveJoint(joint=1, angle_deg=60.0, wait_reached=True, timeout_s=10.0)
    with ThreadPoolExecutor(max_workers=2) as pool:
        replies = list(pool.map(lambda a: client.command(a, move), ["a1", "a3"]))
    for reply in replies:
        assert not reply.ok and reply.error is not None, reply
        assert reply.error.code == m.ErrorCode.REJECTED and "force limit" in reply.error.message
    assert time.monotonic() - started < 5.0
    for arm in ("a1", "a3"):
        limited = [e for e in events[arm] if e.force_limited and e.joint == 1]
        assert limited, events
        assert limited[0].method in ("stall", "status", "oscillation")  # not the model
        measured = wait_until(lambda a=arm: client.snapshot()[a][1], 2.0).angles_deg[1]
        assert 14.0 < measured < 20.0, (arm, measured)
    for sub in subs:
        sub.undeclare()
