"""A G1 end to end on real DDS and Zenoh: the simulated high-level service (``fleet sim``),
a devices agent relaying ``rt/sportmodestate`` and calling the LocoClient RPC, a router and a
plain client. Stop with both actions; refusals in a dynamic state."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from fleet.g1.kind import KIND
from fleet.g1.messages import (
    BalanceStand,
    ContinuousGait,
    G1State,
    GetFsmId,
    SetVelocity,
    StandUp,
    Start,
    StopMove,
)
from fleet.wire import keys
from fleet.wire.messages import ErrorCode
from testkit.collect import Collector, agent_token
from testkit.harness import FleetHarness, wait_until
from testkit.kinds import G1_LOWSTATE_SLOW

STATE = KIND.payloads[keys.STATE]


@contextmanager
def g1_fleet(tmp_path, extra: str) -> Iterator[FleetHarness]:  # type: ignore[no-untyped-def]
    """Router, the simulated G1 h1 (``extra``: its inventory table) and its devices agent."""
    with FleetHarness(tmp_path, arms=1, extra=extra) as harness:
        harness.start_router()
        harness.start_sim()
        harness.start("devices", ["-m", "edge_agent", "--device", "h1"])
        yield harness


@pytest.fixture(params=["stop_move", "damp"])
def fleet(request: pytest.FixtureRequest, tmp_path) -> Iterator[FleetHarness]:  # type: ignore[no-untyped-def]
    extra = f'[g1.h1]\nstop_action = "{request.param}"\nmax_duration_s = 5.0\n{G1_LOWSTATE_SLOW}'
    with g1_fleet(tmp_path, extra) as harness:
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
        # Continuous gait (SetBalanceMode 1, allowed while dynamic): it would keep stepping at
        # zero velocity; the stop's calls end it (issue 22).
        assert client.device_command("h1", ContinuousGait(on=True)).ok
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
        # balance_stand (continuous gait's way out) passes the latch too.
        balance = client.device_command("h1", BalanceStand())
        if action == "damp":
            assert balance.error is not None and "robot answered 3205" in balance.error.message
        else:
            assert balance.ok, balance
        client.reset()
        wait_until(lambda: (s := states.latest()) is not None and not s.estopped, 3.0)
        assert client.device_command("h1", Start()).ok
        wait_until(lambda: (s := states.latest()) is not None and s.fsm_id == 500, 3.0)
    finally:
        states.close()


def test_g1_service_auto_finds_loco_and_status_and_doctor_show_it(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """ai_sport < 8.2 serves ``loco``: ``service = "auto"`` asks both names and uses it."""
    extra = f'[g1.h1]\nservice = "auto"\nsim_service = "loco"\n{G1_LOWSTATE_SLOW}'
    with g1_fleet(tmp_path, extra) as harness:
        client = harness.client()
        key = keys.KeySpace(harness.inventory.fleet).device("g1", "h1", keys.STATE)
        states: Collector[G1State] = Collector(client.session, key, STATE.decode)
        try:
            wait_until(lambda: (s := states.latest()) is not None and s.service == "loco", 30.0)
            state = states.latest()
            assert state is not None and state.service_answered and state.service_setting == "auto"
            wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)
            got = client.device_command("h1", GetFsmId())
            assert got.ok and got.result == "500", got
        finally:
            states.close()
        inventory = ["--inventory", str(harness.inventory_path)]
        fleet = [sys.executable, "-m", "fleet.cli.main"]
        status = subprocess.run(
            [*fleet, "status", *inventory], capture_output=True, text=True, timeout=60
        )
        assert "service loco (auto)" in status.stdout, status.stdout
        doctor = subprocess.run(
            [*fleet, "doctor", *inventory], capture_output=True, text=True, timeout=90
        )
        line = "[ OK ] LocoClient service of g1/h1: loco (auto): answered GetFsmId"
        assert line in doctor.stdout, doctor.stdout
