"""Dex1-1 grippers end to end on real DDS and Zenoh: simulated grippers of both families
(``fleet sim``), a devices agent (``edge-agent --device``), a router and a plain client."""

from __future__ import annotations

import math
import subprocess
import sys
from collections.abc import Iterator

import pytest

from fleet.dex1.kind import KIND
from fleet.dex1.messages import GripEvent, GripperHold, GripperMove, GripperState
from fleet.wire import keys
from fleet.wire.messages import ErrorCode
from testkit.collect import Collector, agent_token
from testkit.harness import FleetHarness, wait_until

STATE = KIND.payloads[keys.STATE]
CONTACT = KIND.payloads[keys.CONTACT]


def _grippers(family: str) -> str:
    return (
        f'[grippers.gl]\nfamily = "{family}"\nmount = "a1"\n\n'
        f'[grippers.gr]\nfamily = "{family}"\nside = "right"\nsim_object_rad = 2.0\n'
    )


@pytest.fixture(params=["go", "hg"])
def fleet(request: pytest.FixtureRequest, tmp_path) -> Iterator[FleetHarness]:  # type: ignore[no-untyped-def]
    with FleetHarness(tmp_path, arms=1, extra=_grippers(request.param)) as harness:
        harness.start_router()
        harness.start_sim()
        harness.start("devices", ["-m", "edge_agent", "--device", "gl", "--device", "gr"])
        yield harness


def _key(harness: FleetHarness, device: str, channel: str) -> str:
    return keys.KeySpace(harness.inventory.fleet).device("gripper", device, channel)


def _opening(states: Collector[GripperState]) -> float | None:
    latest = states.latest()
    return None if latest is None else latest.opening_pct


def test_gripper_state_commands_grip_and_stop(fleet: FleetHarness) -> None:
    client = fleet.client()
    session = client.session
    states = Collector(session, _key(fleet, "gl", keys.STATE), STATE.decode)
    grips = Collector(session, _key(fleet, "gr", keys.CONTACT), CONTACT.decode)
    try:
        wait_until(lambda: (s := states.latest()) is not None and s.link == "ok", 30.0)
        # State flows before the agent serves commands: its token says it serves them now.
        wait_until(lambda: agent_token(client, "gripper", "gl"), 30.0)
        first = states.latest()
        assert first is not None and first.mount == "a1"
        family = fleet.inventory.device("gl").family  # type: ignore[attr-defined]
        assert first.family == family
        # Open to a percent: the simulated fingers track it.
        reply = client.device_command("gl", GripperMove(open_pct=30.0))
        assert reply.ok, reply
        wait_until(lambda: abs((_opening(states) or 0) - 30.0) < 1.0, 5.0)
        # And to radians.
        assert client.device_command("gl", GripperMove(q_rad=math.pi)).ok
        wait_until(lambda: abs((_opening(states) or 0) - 50.0) < 1.0, 5.0)
        # Out of range or over the inventory's limits: refused, nothing written.
        for bad in (
            GripperMove(q_rad=7.0),
            GripperMove(open_pct=50.0, tau=5.0),
            GripperMove(open_pct=50.0, kp=11.0),
            GripperMove(open_pct=10.0, q_rad=1.0),
        ):
            refused = client.device_command("gl", bad)
            assert not refused.ok and refused.error is not None
            assert refused.error.code == ErrorCode.PARAMETER, refused
        nan = client.device_command("gl", b'{"op": "move", "q_rad": NaN}')
        assert nan.error is not None and nan.error.code == ErrorCode.PARAMETER
        unknown = client.device_command("gl", b'{"op": "dance"}')
        assert unknown.error is not None and unknown.error.code == ErrorCode.NOT_IMPLEMENTED
        # Closing on the object of gr: a grip event from the full-rate stream at the edge.
        assert client.device_command("gr", GripperMove(open_pct=0.0)).ok
        wait_until(lambda: any(g.state == "grip" for g in grips.items), 5.0)
        grip: GripEvent = next(g for g in grips.items if g.state == "grip")
        assert abs(grip.q_rad - 2.0) < 0.05 and grip.target_rad == 0.0
        # A fleet stop holds every gripper, confirmed from its state; motion is refused.
        acks = client.estop(timeout_s=5.0)
        for device in ("gripper/gl", "gripper/gr"):
            ack = acks[device]
            assert ack is not None and ack.done, acks
        assert client.device_command("gl", GripperMove(open_pct=80.0)).error.code == 4002  # type: ignore[union-attr]
        assert client.device_command("gl", GripperHold()).ok  # a hold is always allowed
        wait_until(lambda: (s := states.latest()) is not None and s.estopped, 3.0)
        client.reset()
        wait_until(lambda: (s := states.latest()) is not None and not s.estopped, 3.0)
        assert client.device_command("gl", GripperMove(open_pct=80.0)).ok
        wait_until(lambda: abs((_opening(states) or 0) - 80.0) < 1.0, 5.0)
        # fleet status lists the grippers with their opening (the arm has no agent here).
        status = subprocess.run(
            [
                sys.executable,
                "-m",
                "fleet.cli.main",
                "status",
                "--inventory",
                str(fleet.inventory_path),
            ],
            capture_output=True,
            text=True,
            timeout=30,
        )
        line = next(x for x in status.stdout.splitlines() if x.startswith("gripper/gl"))
        assert "open  80.0 %" in line and "on a1" in line, status.stdout
    finally:
        states.close()
        grips.close()
