"""Unitree's own SDK (testkit/sdk_g1.py) as the far side of the G1, on real CycloneDDS (loopback,
the test's own domain) and real Zenoh:

- its ``LocoClient`` drives our simulated G1 on both service names (``sport`` for ai_sport >=
  8.2, ``loco`` before): walk, the dynamic-state refusal, continuous gait (StopMove alone keeps
  it stepping, ContinuousGait(false) ends it), damp;
- a fake G1 built on its RPC ``Server`` is stopped by ``fleet estop`` through our agent while
  walking in continuous gait, on both names (and ``auto``), confirmed from its sportmodestate
  within 1 s; with no sportmodestate at all (firmware before 1.5.1) damp still reaches it.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest
import unitree_sdk2py  # noqa: F401 - `make` installs it (--no-deps): a missing SDK fails, never skips

from fleet.g1.kind import KIND
from fleet.g1.messages import (
    BalanceStand,
    ContinuousGait,
    Damp,
    G1State,
    GetBalanceMode,
    GetFsmId,
    GetFsmMode,
    HighStand,
    Lie2StandUp,
    LowStand,
    Move,
    SetFsmId,
    SetSpeedMode,
    SetStandHeight,
    SetTaskId,
    SetVelocity,
    ShakeHand,
    Sit,
    Squat,
    Squat2StandUp,
    StandUp,
    StandUp2Squat,
    Start,
    StopMove,
    WaveHand,
    ZeroTorque,
)
from fleet.wire import keys
from fleet.wire.messages import ErrorCode
from testkit.collect import Collector, agent_token
from testkit.harness import FleetHarness, wait_until
from testkit.kinds import G1_LOWSTATE_SLOW

STATE = KIND.payloads[keys.STATE]
CONFIRM_GOAL_S = 1.0
"""Issue 22: a stop of a walking G1 confirmed within 1 s, on both service names."""


def _sdk(harness: FleetHarness, name: str, *argv: str) -> subprocess.Popen[bytes]:
    args = ["-m", "testkit.sdk_g1", *argv, "--domain", str(harness.domain)]
    return harness.start(name, args, inventory=False)


def _calls(harness: FleetHarness, name: str) -> list[dict]:
    return [
        json.loads(line) for line in harness.log(name).splitlines() if line.startswith('{"api_id"')
    ]


@pytest.mark.parametrize("service", ["sport", "loco"])
def test_unitree_loco_client_drives_our_simulator(tmp_path, service: str) -> None:  # type: ignore[no-untyped-def]
    extra = f'[g1.h1]\nsim_service = "{service}"\nsim_settle_s = 0.3\n{G1_LOWSTATE_SLOW}'
    with FleetHarness(tmp_path, arms=1, extra=extra) as harness:
        harness.start_router()
        harness.start_sim()
        client = _sdk(harness, "sdk-client", "client", "--service", service)
        try:
            client.wait(timeout=60)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the SDK's client did not finish:\n{harness.log('sdk-client')}")
        lines = [x for x in harness.log("sdk-client").splitlines() if x.startswith('{"service"')]
        assert client.returncode == 0 and lines, harness.log("sdk-client")
        out = json.loads(lines[-1])
    assert out["service"] == service
    assert out["state_s"] is not None
    assert out["get_fsm_id"] == [0, '{"data": 500}']
    assert out["walk"] == 0 and out["walk_dynamic_s"] is not None
    assert out["stand_up_while_dynamic"] == 3205  # seed 004: no mode switch while dynamic
    assert out["continuous_on"] == 0 and out["balance_mode"] == [0, '{"data": 1}']
    assert out["stop_move"] == 0
    assert out["static_after_stop_move_s"] is None, out  # continuous gait keeps stepping
    assert out["continuous_off"] == 0  # allowed while dynamic: the way out
    assert out["static_after_continuous_off_s"] is not None, out
    assert out["damp"] == 0 and out["damped_s"] is not None
    assert out["set_task_id"] == 3205  # an arm task needs a standing controller
    print(f"LocoClient on {service!r}: {out}")


def _fleet(tmp_path, service: str, setting: str, action: str, *flags: str) -> FleetHarness:  # type: ignore[no-untyped-def]
    extra = (
        f'[g1.h1]\nsimulated = false\nservice = "{setting}"\nstop_action = "{action}"\n'
        "max_duration_s = 5.0\n"
    )
    harness = FleetHarness(tmp_path, arms=1, extra=extra)
    harness.start_router()
    server = _sdk(harness, "fake-g1", "server", "--service", service, *flags)
    wait_until(lambda: '"ready"' in harness.log("fake-g1") or server.poll() is not None, 30.0)
    assert server.poll() is None, harness.log("fake-g1")
    harness.start("devices", ["-m", "edge_agent", "--device", "h1"])
    return harness


@pytest.fixture
def closing() -> Iterator[list[FleetHarness]]:
    harnesses: list[FleetHarness] = []
    yield harnesses
    for harness in harnesses:
        harness.close()


@pytest.mark.parametrize(
    ("service", "setting"), [("sport", "sport"), ("loco", "loco"), ("loco", "auto")]
)
def test_fleet_estop_stops_a_fake_g1_on_unitrees_server(
    tmp_path,  # type: ignore[no-untyped-def]
    closing: list[FleetHarness],
    service: str,
    setting: str,
) -> None:
    harness = _fleet(tmp_path, service, setting, "stop_move")
    closing.append(harness)
    client = harness.client()
    key = keys.KeySpace(harness.inventory.fleet).device("g1", "h1", keys.STATE)
    states: Collector[G1State] = Collector(client.session, key, STATE.decode)
    try:
        wait_until(lambda: (s := states.latest()) is not None and s.service_answered, 30.0)
        wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)
        first = states.latest()
        assert first is not None and (first.service, first.service_setting) == (service, setting)
        # Walking, in continuous gait (it would keep stepping at zero velocity).
        assert client.device_command("h1", SetVelocity(vx=0.3, duration_s=5.0)).ok
        assert client.device_command("h1", ContinuousGait(on=True)).ok
        wait_until(lambda: (s := states.latest()) is not None and s.mode == "dynamic", 3.0)
        before = len(_calls(harness, "fake-g1"))
        cli = [sys.executable, "-m", "fleet.cli.main", "estop", "h1", "--timeout", "3"]
        done = subprocess.run(
            [*cli, "--inventory", str(harness.inventory_path)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0, (done.stdout, done.stderr, harness.log("devices")[-2000:])
        line = next(x for x in done.stdout.splitlines() if x.startswith("g1/h1:"))
        match = re.search(r"confirmed \+([\d.]+) ms", line)
        assert match is not None, line
        confirmed_s = float(match.group(1)) / 1000
        print(f"fleet estop of a walking G1 (continuous gait), service {setting!r}: {line}")
        assert confirmed_s <= CONFIRM_GOAL_S, line
        # What reached the robot, each write in order: StopMove, then ContinuousGait(false)
        # (both delivered through the SDK server's request reader, depth 1 by its defaults).
        calls = [(c["api_id"], c["parameter"], c["code"]) for c in _calls(harness, "fake-g1")]
        stop_move = (7105, '{"velocity": [0.0, 0.0, 0.0], "duration": 1.0}', 0)
        assert calls[before : before + 2] == [stop_move, (7102, '{"data": 0}', 0)], calls
        latest = states.latest()
        assert latest is not None and latest.mode == "static" and latest.fsm_id == 500
    finally:
        states.close()


def test_damp_reaches_a_g1_without_state(tmp_path, closing: list[FleetHarness]) -> None:  # type: ignore[no-untyped-def]
    """Firmware before 1.5.1: no rt/sportmodestate. Damp is never refused for it; a damp stop
    is written, reported ``unconfirmed: no state`` and repeated until reset."""
    harness = _fleet(tmp_path, "sport", "sport", "damp", "--no-state")
    closing.append(harness)
    client = harness.client()
    wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)

    def damps() -> int:
        return sum(
            c["api_id"] == 7101 and c["parameter"] == '{"data": 1}'
            for c in _calls(harness, "fake-g1")
        )

    reply = client.device_command("h1", Damp())
    assert reply.ok, reply  # the robot answered 0
    assert damps() == 1
    start = time.monotonic()
    acks = client.estop(timeout_s=1.0)
    ack = acks["g1/h1"]
    assert ack is not None and not ack.done and ack.dds_written_ns is not None, acks
    assert ack.detail is not None and ack.detail.startswith("unconfirmed: no state"), ack
    # Repeated (every 0.2 s) while unconfirmed ...
    wait_until(lambda: damps() >= 4, 3.0)
    print(f"damp stop without state: {damps() - 1} writes in {time.monotonic() - start:.2f} s")
    # ... until the operator resets: then no more.
    client.reset()

    def released() -> bool:  # refused now for the missing state, no longer for the stop
        error = client.device_command("h1", StandUp()).error
        return error is not None and "no fresh" in error.message

    wait_until(released, 5.0)
    after = damps()
    with pytest.raises(AssertionError):  # three repeat periods without one (one in flight)
        wait_until(lambda: damps() > after + 1, 0.6)


def test_every_loco_client_call_reaches_unitrees_server(  # type: ignore[no-untyped-def]
    tmp_path, closing: list[FleetHarness]
) -> None:
    """Issue 23: every LocoClient call of seed 004 and Unitree's SDK, sent as fleet commands
    through the agent (under its lease, its checks) to a fake G1 on the SDK's RPC ``Server``:
    each reaches it as the SDK's own client sends it, reads answer with the value, and the
    static/dynamic rules refuse before anything is written."""
    harness = _fleet(tmp_path, "sport", "sport", "stop_move")
    closing.append(harness)
    client = harness.client()
    key = keys.KeySpace(harness.inventory.fleet).device("g1", "h1", keys.STATE)
    states: Collector[G1State] = Collector(client.session, key, STATE.decode)

    def fsm_is(fsm_id: int) -> bool:
        return (s := states.latest()) is not None and s.fsm_id == fsm_id and s.mode == "static"

    try:
        wait_until(lambda: (s := states.latest()) is not None and s.service_answered, 30.0)
        wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)
        before = len(_calls(harness, "fake-g1"))
        reads = [(GetFsmId(), "500"), (GetFsmMode(), "0"), (GetBalanceMode(), "0")]
        for command, result in reads:
            reply = client.device_command("h1", command)
            assert reply.ok and reply.result == result, (command, reply)
        expected: list[tuple[int, dict]] = [(7001, {}), (7002, {}), (7003, {})]
        sequence: list[tuple[Any, int, dict, int | None]] = [
            (SetSpeedMode(mode=1), 7107, {"data": 1}, None),
            (HighStand(), 7104, {"data": 4294967295}, None),
            (LowStand(), 7104, {"data": 0}, None),
            (SetStandHeight(height=0.5), 7104, {"data": 0.5}, None),
            (WaveHand(), 7106, {"data": 0}, None),
            (WaveHand(turn=True), 7106, {"data": 1}, None),
            (ShakeHand(stage=0), 7106, {"data": 2}, None),
            (ShakeHand(stage=1), 7106, {"data": 3}, None),
            (SetTaskId(task_id=0), 7106, {"data": 0}, None),
            (Move(vx=0.2), 7105, {"velocity": [0.2, 0.0, 0.0], "duration": 1.0}, -1),
            (StopMove(), 7105, {"velocity": [0.0, 0.0, 0.0], "duration": 1.0}, 500),
            (Squat(), 7101, {"data": 2}, 2),
            (Squat2StandUp(), 7101, {"data": 706}, 706),
            (StandUp2Squat(), 7101, {"data": 706}, 706),
            (SetFsmId(fsm_id=501), 7101, {"data": 501}, 501),
            (StandUp(), 7101, {"data": 4}, 4),
            (Sit(), 7101, {"data": 3}, 3),
            (Lie2StandUp(), 7101, {"data": 702}, 702),
            (Damp(), 7101, {"data": 1}, 1),
            (ZeroTorque(), 7101, {"data": 0}, 0),
            (Damp(), 7101, {"data": 1}, 1),
            (Start(), 7101, {"data": 500}, 500),
            (BalanceStand(), 7102, {"data": 0}, 500),
        ]
        for command, api_id, parameter, fsm in sequence:
            reply = client.device_command("h1", command)
            assert reply.ok, (command, reply, harness.log("fake-g1")[-1500:])
            expected.append((api_id, parameter))
            if fsm == -1:  # walking: then StopMove, and the state must show it static again
                wait_until(lambda: (s := states.latest()) is not None and s.mode == "dynamic", 3.0)
            elif fsm is not None:  # the agent checks the next call against the state it sees
                wait_until(lambda fsm=fsm: fsm_is(fsm), 5.0)
        calls = [
            (c["api_id"], json.loads(c["parameter"]), c["code"]) for c in _calls(harness, "fake-g1")
        ]
        got = [(a, p) for a, p, code in calls[before:] if a != 7001 or not p]
        assert got == expected, got
        assert all(code == 0 for _, _, code in calls[before:]), calls
        # Refused by the agent, nothing written: an unbounded move, an id not in the seed's
        # table, zero torque while standing, a mode switch while walking.
        refused = [
            (Move(vx=0.2, continuous=True), ErrorCode.PARAMETER, "allow_continuous_move"),
            (SetFsmId(fsm_id=123), ErrorCode.PARAMETER, "not in seed 004's table"),
            (ZeroTorque(), ErrorCode.REJECTED, "only from damping"),
        ]
        written = len(_calls(harness, "fake-g1"))
        for command, code, why in refused:
            reply = client.device_command("h1", command)
            assert reply.error is not None and reply.error.code == code, (command, reply)
            assert why in reply.error.message, reply.error.message
        assert client.device_command("h1", SetVelocity(vx=0.3, duration_s=2.0)).ok
        wait_until(lambda: (s := states.latest()) is not None and s.mode == "dynamic", 3.0)
        reply = client.device_command("h1", Sit())
        assert reply.error is not None and "dynamic state" in reply.error.message, reply
        assert len(_calls(harness, "fake-g1")) == written + 1  # only the velocity
    finally:
        states.close()
