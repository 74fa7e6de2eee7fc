"""One arm end to end: simulated arm + agent + router + a plain client, all real processes."""

from __future__ import annotations

from fleet.wire import messages as m
from tests.harness import FleetHarness, wait_until


def test_move_joints_is_acknowledged_and_reached(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    target = [10.0, -30.0, 40.0, 0.0, 20.0, 5.0, 10.0]
    reply = client.command("a1", m.MoveJoints(angles_deg=target, mode=1, wait_reached=True))
    assert reply.ok, reply.error
    assert reply.received and reply.reached
    assert reply.seq is not None and reply.seq != 10
    _status, joints = client.snapshot(["a1"])["a1"]
    assert joints is not None
    assert all(abs(a - t) <= 2.0 for a, t in zip(joints.angles_deg, target))
