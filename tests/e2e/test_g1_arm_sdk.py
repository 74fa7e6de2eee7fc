"""Issue 23: the G1's waist and arms through rt/arm_sdk, end to end on real DDS and Zenoh: our
agent streams to a fake G1 built on Unitree's SDK (testkit/sdk_g1.py ``server --arms``: its
``ChannelSubscriber`` takes rt/arm_sdk and checks each message with the SDK's ``CRC``; its
``ChannelPublisher`` sends rt/lowstate sealed with it).

Bad targets are refused with the reason and nothing reaches the robot; a target engages the
weight 0 -> 1 in steps <= 0.05; a fleet stop releases the arms (1 -> 0 over >= 1 s) and only
then writes StopMove; a forbidden FSM refuses targets. The stream's jitter is measured at the
receiver."""

from __future__ import annotations

import json

import pytest

from fleet.g1.kind import KIND
from fleet.g1.messages import ArmTarget, Damp, G1LowState, G1State
from fleet.wire import keys
from fleet.wire.messages import ErrorCode
from testkit.collect import Collector, agent_token
from testkit.harness import FleetHarness, wait_until
from tests.e2e.test_g1_sdk import _calls, _fleet
from tests.e2e.test_g1_sdk import closing as closing  # the fixture

STATE = KIND.payloads[keys.STATE]
LOWSTATE = KIND.payloads[keys.LOWSTATE]
STOP_MOVE = (7105, '{"velocity": [0.0, 0.0, 0.0], "duration": 1.0}')


def _arm_lines(harness: FleetHarness) -> list[dict]:
    return [json.loads(x) for x in harness.log("fake-g1").splitlines() if x.startswith('{"arm"')]


def _target(**joints: float) -> list[float]:
    q = [0.0] * 17
    for name, value in joints.items():
        q[int(name[1:])] = value
    return q


@pytest.mark.timing
def test_arm_sdk_stream_to_a_fake_g1_on_unitrees_sdk(  # type: ignore[no-untyped-def]
    tmp_path, closing: list[FleetHarness]
) -> None:
    harness = _fleet(tmp_path, "sport", "sport", "stop_move", "--arms")
    closing.append(harness)
    client = harness.client()
    space = keys.KeySpace(harness.inventory.fleet)
    states: Collector[G1State] = Collector(
        client.session, space.device("g1", "h1", keys.STATE), STATE.decode
    )
    lows: Collector[G1LowState] = Collector(
        client.session, space.device("g1", "h1", keys.LOWSTATE), LOWSTATE.decode
    )
    try:
        wait_until(lambda: (s := states.latest()) is not None and s.service_answered, 30.0)
        wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)
        wait_until(lambda: lows.latest() is not None, 10.0)
        low = lows.latest()
        assert low is not None and len(low.q_rad) == 29 and low.bad_samples == 0
        # Bad input: refused with the reason, nothing reaches the robot.
        bad = [
            (ArmTarget(q_rad=_target(), speed_rad_s=5.0), "too fast"),
            (ArmTarget(q_rad=_target(j1=0.6)), "waist_roll (motor 13) 0.6 rad is outside"),
            (ArmTarget(q_rad=_target(j6=0.9)), "from the measured 0"),
        ]
        for command, why in bad:
            reply = client.device_command("h1", command)
            assert reply.error is not None and reply.error.code == ErrorCode.PARAMETER, reply
            assert why in reply.error.message, reply.error.message
        nan = (
            b'{"op": "arm_target", "q_rad": [NaN, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]}'
        )
        reply = client.device_command("h1", nan)
        assert reply.error is not None and reply.error.code == ErrorCode.PARAMETER, reply
        assert _arm_lines(harness) == []
        # Engage: 0 -> 1, steps <= 0.05, every message sealed as the SDK seals it.
        assert client.device_command("h1", ArmTarget(q_rad=_target(j0=0.3))).ok
        wait_until(lambda: any(a["arm"] == 1 and a["q12"] == 0.3 for a in _arm_lines(harness)), 5)
        wait_until(lambda: (s := states.latest()) is not None and s.arm_phase == "on", 3.0)
        engaged = len(_arm_lines(harness))
        # A stop: the arms released over >= 1 s, then StopMove.
        client.estop(timeout_s=0.5)
        wait_until(
            lambda: (
                STOP_MOVE in [(c["api_id"], c["parameter"]) for c in _calls(harness, "fake-g1")]
            ),
            5.0,
        )
        lines = [json.loads(x) for x in harness.log("fake-g1").splitlines() if x.startswith("{")]
        arm = [x for x in lines if "arm" in x]
        assert all(a["crc_ok"] for a in arm), [a for a in arm if not a["crc_ok"]][:3]
        weights = [a["arm"] for a in arm]
        steps = [abs(b - a) for a, b in zip([0.0, *weights], weights, strict=False)]
        assert max(steps) <= 0.05 + 1e-6, max(steps)
        released = next(i for i in range(engaged, len(arm)) if arm[i]["arm"] < 1.0)
        zero = next(i for i in range(released, len(arm)) if arm[i]["arm"] == 0.0)
        ramp_s = arm[zero]["t"] - arm[released - 1]["t"]
        assert ramp_s >= 1.0 - 0.03, ramp_s
        order = [
            ("arm0" if x.get("arm") == 0.0 else (x.get("api_id"), x.get("parameter")))
            for x in lines
        ]
        assert order.index(STOP_MOVE) > order.index("arm0"), (
            "StopMove before the arms were released"
        )
        gaps = [(b["t"] - a["t"]) * 1000 for a, b in zip(arm, arm[1:], strict=False)]
        jitter = sorted(abs(g - 20.0) for g in gaps)
        p99 = jitter[int(0.99 * (len(jitter) - 1))]
        print(f"arm_sdk: {len(arm)} messages, release ramp {ramp_s:.3f} s, jitter p99 {p99:.2f} ms")
        wait_until(lambda: (s := states.latest()) is not None and s.arm_phase == "off", 3.0)
        # A forbidden FSM: damping refuses targets.
        client.reset()
        assert client.device_command("h1", Damp()).ok
        wait_until(lambda: (s := states.latest()) is not None and s.fsm_id == 1, 3.0)
        before = len(_arm_lines(harness))
        reply = client.device_command("h1", ArmTarget(q_rad=_target()))
        assert (
            reply.error is not None and "lock standing (4) and the walking" in reply.error.message
        )
        # Nothing of it reached the robot: a message still on its way from the release ramp
        # may land in the fake's log after ``before`` was read, but the weight never rises.
        weights = [line["arm"] for line in _arm_lines(harness)[max(before - 1, 0) :]]
        assert all(b <= a for a, b in zip(weights, weights[1:], strict=False)), weights
    finally:
        states.close()
        lows.close()
