"""A G1 end to end on real DDS and Zenoh: the simulated high-level service (``fleet sim``),
a devices agent relaying ``rt/sportmodestate`` and calling the LocoClient RPC, a router and a
plain client. Stop with both actions; refusals in a dynamic state."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from fleet.g1.kind import KIND
from fleet.g1.messages import G1State, GetFsmId, SetVelocity, StandUp, Start, StopMove
from fleet.wire import keys
from fleet.wire.messages import ErrorCode
from tests.harness import FleetHarness, wait_until
from tests.test_dex1_end_to_end import agent_token
from tests.test_end_to_end import Collector

STATE = KIND.payloads[keys.STATE]


@pytest.fixture(params=["stop_move", "damp"])
def fleet(request: pytest.FixtureRequest, tmp_path) -> Iterator[FleetHarness]:  # type: ignore[no-untyped-def]
    extra = f'[g1.h1]\nstop_action = "{request.param}"\nmax_duration_s = 5.0\n'
    with FleetHarness(tmp_path, arms=1, extra=extra) as harness:
        harness.start_router()
        harness.start_sim()
        harness.start("devices", ["-m", "edge_agent", "--device", "h1"])
        yield harness


def test_g1_state_rpc_refusals_and_stop(fleet: FleetHarness) -> None:
    client = fleet.client()
    key = keys.KeySpace(fleet.inventory.fleet).device("g1", "h1", keys.STATE)
    states: Collector[G1State] = Collector(client.session, key, STATE.decode)
    action = fleet.inventory.device("h1").stop_action  # type: ignore[attr-defined]
    try:
        wait_until(lambda: (s := states.latest()) is not None and s.link == "ok", 30.0)
        wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)  # it serves commands now
        first = states.latest()
        assert first is not None and (first.fsm_id, first.fsm_name, first.mode) == (
            500,
            "walk",
            "static",
        )
        got = client.device_command("h1", GetFsmId())
        assert got.ok and got.result == "500", got
        # Bounds first: nothing out of range reaches the robot.
        for bad in (SetVelocity(vx=2.0), SetVelocity(vx=0.1, duration_s=30.0)):
            refused = client.device_command("h1", bad)
            assert refused.error is not None and refused.error.code == ErrorCode.PARAMETER
        # Walking: the robot is in a dynamic state ...
        assert client.device_command("h1", SetVelocity(vx=0.3, duration_s=4.0)).ok
        wait_until(lambda: (s := states.latest()) is not None and s.mode == "dynamic", 3.0)
        # ... where seed 004 refuses a mode switch: the agent refuses it, naming why.
        for switch in (Start(), StandUp()):
            refused = client.device_command("h1", switch)
            assert refused.error is not None and refused.error.code == ErrorCode.REJECTED
            assert "dynamic state (fsm_mode 1" in refused.error.message, refused
        # A fleet stop: the G1's action, confirmed from sportmodestate, latched.
        acks = client.estop(timeout_s=5.0)
        ack = acks["g1/h1"]
        assert ack is not None and ack.done and ack.action == action, (
            acks,
            states.items[-3:],
            fleet.log("devices")[-2000:],
        )
        latest = states.latest()
        wait_until(lambda: (s := states.latest()) is not None and s.estopped, 2.0)
        latest = states.latest()
        assert latest is not None
        if action == "damp":
            assert latest.fsm_id == 1 and latest.fsm_name == "damping"
        else:
            assert latest.mode == "static" and latest.fsm_id == 500
        refused = client.device_command("h1", SetVelocity(vx=0.1))
        assert refused.error is not None and refused.error.code == ErrorCode.REJECTED
        assert "stopped" in refused.error.message
        # stop_move passes the latch; a damped robot itself refuses velocity (no walking).
        stop_move = client.device_command("h1", StopMove())
        if action == "damp":
            assert stop_move.error is not None and "robot answered 3205" in stop_move.error.message
        else:
            assert stop_move.ok, stop_move
        client.reset()
        wait_until(lambda: (s := states.latest()) is not None and not s.estopped, 3.0)
        assert client.device_command("h1", Start()).ok
        wait_until(lambda: (s := states.latest()) is not None and s.fsm_id == 500, 3.0)
    finally:
        states.close()
