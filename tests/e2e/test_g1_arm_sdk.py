"""The G1's waist and arms through rt/arm_sdk, end to end on real DDS and Zenoh: our agent
streams to a fake G1 built on Unitree's SDK (testkit/sdk_g1.py ``server --arms``: its
``ChannelSubscriber`` takes rt/arm_sdk and checks each message with the SDK's ``CRC``; its
``ChannelPublisher`` sends rt/lowstate sealed with it; its pose keeps the last message's blend,
as the robot keeps a stream's weight when its writer goes away).

Bad targets are refused with the reason and nothing reaches the robot; a new agent, not knowing
the weight the robot holds, starts at weight 1 on the measured pose (Unitree's example) and
copies the robot's mode_machine into every message; a fleet stop writes StopMove (or damp) at
once while the arms stream, and holds them where they are (weight kept) until an explicit
release, which ramps 1 -> 0 over >= 3 s; a forbidden FSM refuses targets. An agent killed with
the arms held and restarted takes them where they are (no drop of the weight); SIGTERM releases
them before the agent exits. Every bad rt/lowstate sample is counted. The stream's jitter is
measured at the receiver."""

from __future__ import annotations

import json
import signal
import time

import pytest

from fleet.g1.arms import MIN_RELEASE_S, PERIOD_S
from fleet.g1.kind import KIND
from fleet.g1.messages import ArmRelease, ArmTarget, Damp, G1LowState, G1State
from fleet.wire import keys
from fleet.wire.messages import ErrorCode
from testkit.collect import Collector, agent_token
from testkit.harness import FleetHarness, wait_until
from tests.e2e.test_g1_sdk import _calls, _fleet
from tests.e2e.test_g1_sdk import closing as closing  # the fixture

STATE = KIND.payloads[keys.STATE]
LOWSTATE = KIND.payloads[keys.LOWSTATE]
STOP_MOVE = (7105, '{"velocity": [0.0, 0.0, 0.0], "duration": 1.0}')
STOP_MOVE_GOAL_S = 0.3
"""A stop's StopMove reaches the robot within this while the arms stream (it took 1.0-1.4 s
when it waited for the arms' release)."""
RAMP_STEP = PERIOD_S / MIN_RELEASE_S + 1e-4


def _arm_lines(harness: FleetHarness, since_s: float = 0.0) -> list[dict]:
    lines = [json.loads(x) for x in harness.log("fake-g1").splitlines() if x.startswith('{"arm"')]
    return [line for line in lines if line["t"] > since_s]


def _target(**joints: float) -> list[float]:
    q = [0.0] * 17
    for name, value in joints.items():
        q[int(name[1:])] = value
    return q


def _collectors(harness: FleetHarness) -> tuple[Collector[G1State], Collector[G1LowState]]:
    client = harness.client()
    space = keys.KeySpace(harness.inventory.fleet)
    states: Collector[G1State] = Collector(
        client.session, space.device("g1", "h1", keys.STATE), STATE.decode
    )
    lows: Collector[G1LowState] = Collector(
        client.session, space.device("g1", "h1", keys.LOWSTATE), LOWSTATE.decode
    )
    wait_until(lambda: (s := states.latest()) is not None and s.service_answered, 30.0)
    wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)
    wait_until(lambda: lows.latest() is not None, 10.0)
    return states, lows


def _release_ramp(lines: list[dict]) -> float:
    """The seconds a release took from the last message at weight 1 to the first at 0, its
    steps checked (never faster than Unitree's example) and the pose held meanwhile."""
    weights = [a["arm"] for a in lines]
    start = max(i for i, w in enumerate(weights) if w == 1.0)
    zero = next(i for i in range(start, len(weights)) if weights[i] == 0.0)
    ramp = lines[start : zero + 1]
    steps = [a["arm"] - b["arm"] for a, b in zip(ramp, ramp[1:], strict=False)]
    assert all(0.0 <= s <= RAMP_STEP for s in steps), max(steps)
    assert len({a["q12"] for a in ramp}) == 1, "the pose moved while releasing"
    return float(lines[zero]["t"] - lines[start]["t"])


@pytest.mark.timing
def test_arm_sdk_stream_to_a_fake_g1_on_unitrees_sdk(  # type: ignore[no-untyped-def]
    tmp_path, closing: list[FleetHarness]
) -> None:
    harness = _fleet(tmp_path, "sport", "sport", "stop_move", "--arms", "--mode-machine", "5")
    closing.append(harness)
    client = harness.client()
    states, lows = _collectors(harness)
    try:
        low = lows.latest()
        assert low is not None and len(low.q_rad) == 29 and low.bad_samples == 0
        assert (s := states.latest()) is not None and s.arm_weight is None, s  # not known yet
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
        # Engage with the robot's weight unknown: weight 1 on the measured pose from the first
        # message (Unitree's example), the pose then moving at the speed limit; the robot's
        # mode_machine in every message, every message sealed as the SDK seals it.
        assert client.device_command("h1", ArmTarget(q_rad=_target(j0=0.3))).ok
        wait_until(lambda: any(a["arm"] == 1 and a["q12"] == 0.3 for a in _arm_lines(harness)), 5)
        first = _arm_lines(harness)[0]
        assert first["arm"] == 1.0 and abs(first["q12"]) <= 0.5 * PERIOD_S + 1e-4, first
        wait_until(lambda: (s := states.latest()) is not None and s.arm_phase == "on", 3.0)
        # A stop while the arms stream: StopMove goes out at once, the arms are held.
        streamed = len(_arm_lines(harness))
        asked = time.monotonic()
        client.estop(timeout_s=0.5)
        wait_until(
            lambda: (
                STOP_MOVE in [(c["api_id"], c["parameter"]) for c in _calls(harness, "fake-g1")]
            ),
            5.0,
        )
        stop_move = next(
            c for c in _calls(harness, "fake-g1") if (c["api_id"], c["parameter"]) == STOP_MOVE
        )
        latency_s = stop_move["t"] - asked
        wait_until(lambda: (s := states.latest()) is not None and s.arm_phase == "holding", 3.0)
        time.sleep(0.5)  # pacing: a window in which the held arms must not move
        held = _arm_lines(harness)[streamed:]
        assert len(held) >= 20 and all(a["arm"] == 1.0 and a["q12"] == 0.3 for a in held), held[-3:]
        assert abs(lows.latest().q_rad[12] - 0.3) < 1e-3  # type: ignore[union-attr]
        assert latency_s < STOP_MOVE_GOAL_S, f"StopMove {latency_s:.3f} s after the stop"
        # Released only when asked (allowed under the stop): 1 -> 0 over >= 3 s.
        assert client.device_command("h1", ArmRelease()).ok
        wait_until(lambda: (s := states.latest()) is not None and s.arm_phase == "off", 6.0)
        arm = _arm_lines(harness)
        ramp_s = _release_ramp(arm)
        assert ramp_s >= MIN_RELEASE_S - 0.03, ramp_s
        assert all(a["crc_ok"] and a["mode_machine"] == 5 for a in arm), arm[-1]
        gaps = [(b["t"] - a["t"]) * 1000 for a, b in zip(arm, arm[1:], strict=False)]
        jitter = sorted(abs(g - 20.0) for g in gaps)
        p99 = jitter[int(0.99 * (len(jitter) - 1))]
        print(
            f"arm_sdk: {len(arm)} messages, stop -> StopMove {latency_s * 1000:.0f} ms while "
            f"streaming, release ramp {ramp_s:.3f} s, jitter p99 {p99:.2f} ms"
        )
        # A forbidden FSM: damping refuses targets.
        client.reset()
        assert client.device_command("h1", Damp()).ok
        wait_until(lambda: (s := states.latest()) is not None and s.fsm_id == 1, 3.0)
        before = len(_arm_lines(harness))
        reply = client.device_command("h1", ArmTarget(q_rad=_target()))
        assert (
            reply.error is not None and "lock standing (4) and the walking" in reply.error.message
        )
        assert _arm_lines(harness)[before:] == []
    finally:
        states.close()
        lows.close()


def test_a_damp_stop_is_written_at_once_while_the_arms_stream(  # type: ignore[no-untyped-def]
    tmp_path, closing: list[FleetHarness]
) -> None:
    harness = _fleet(tmp_path, "sport", "sport", "damp", "--arms")
    closing.append(harness)
    client = harness.client()
    states, lows = _collectors(harness)
    damp = (7101, '{"data": 1}')
    try:
        assert client.device_command("h1", ArmTarget(q_rad=_target(j0=0.3))).ok
        wait_until(lambda: (s := states.latest()) is not None and s.arm_phase == "on", 5.0)
        asked = time.monotonic()
        client.estop(timeout_s=0.5)
        wait_until(
            lambda: damp in [(c["api_id"], c["parameter"]) for c in _calls(harness, "fake-g1")],
            5.0,
        )
        call = next(c for c in _calls(harness, "fake-g1") if (c["api_id"], c["parameter"]) == damp)
        latency_s = call["t"] - asked
        print(f"stop -> damp {latency_s * 1000:.0f} ms while streaming")
        assert latency_s < STOP_MOVE_GOAL_S, f"damp {latency_s:.3f} s after the stop"
        # Damping takes no rt/arm_sdk: the stream ends, the weight it leaves is unknown.
        wait_until(lambda: (s := states.latest()) is not None and s.arm_phase == "off", 3.0)
        stopped = states.latest()
        assert stopped is not None and stopped.arm_weight is None, stopped
    finally:
        states.close()
        lows.close()


def test_a_restarted_agent_takes_the_held_arms_where_they_are(  # type: ignore[no-untyped-def]
    tmp_path, closing: list[FleetHarness]
) -> None:
    harness = _fleet(tmp_path, "sport", "sport", "stop_move", "--arms")
    closing.append(harness)
    client = harness.client()
    states, lows = _collectors(harness)
    try:
        assert client.device_command("h1", ArmTarget(q_rad=_target(j0=0.3))).ok
        wait_until(lambda: abs(lows.latest().q_rad[12] - 0.3) < 1e-3, 5.0)  # type: ignore[union-attr]
        # The agent dies (no release): the robot keeps the stream's weight and pose.
        harness.stop("devices", signal.SIGKILL)
        restarted = time.monotonic()
        harness.start("devices", ["-m", "edge_agent", "--device", "h1"])
        wait_until(
            lambda: (s := states.latest()) is not None and s.arm_phase == "off" and s.link == "ok",
            30.0,
        )
        assert states.latest().arm_weight is None  # type: ignore[union-attr]
        wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)
        wait_until(lambda: (low := lows.latest()) is not None and low.stamp_ns > 0, 5.0)
        assert client.device_command("h1", ArmTarget(q_rad=_target(j0=0.25))).ok
        wait_until(lambda: any(a["q12"] == 0.25 for a in _arm_lines(harness, restarted)), 5.0)
        new = _arm_lines(harness, restarted)
        # Its first message keeps the weight the robot holds on the pose it holds: the blend
        # (what the fake reports) never drops towards the robot's own pose (0).
        assert new[0]["arm"] == 1.0 and abs(new[0]["q12"] - 0.3) <= 0.5 * PERIOD_S + 1e-4, new[0]
        blended = [a["arm"] * a["q12"] for a in new]
        assert min(blended) >= 0.25 - 1e-4, min(blended)
        # SIGTERM: the arms go back to the robot (1 -> 0 over >= 3 s) before the agent exits.
        terminated = time.monotonic()
        assert harness.stop("devices") == 0
        # (from a little before the signal: the ramp may start within a message of it)
        ramp_s = _release_ramp(_arm_lines(harness, terminated - 0.2))
        assert ramp_s >= MIN_RELEASE_S - 0.03, ramp_s
        print(
            f"restart: first weight {new[0]['arm']}, blend min {min(blended):.3f} rad; "
            f"exit ramp {ramp_s:.3f} s"
        )
    finally:
        states.close()
        lows.close()


def test_every_bad_lowstate_sample_is_counted(  # type: ignore[no-untyped-def]
    tmp_path, closing: list[FleetHarness]
) -> None:
    harness = _fleet(tmp_path, "sport", "sport", "stop_move", "--arms", "--bad-lowstate-every", "2")
    closing.append(harness)
    states, lows = _collectors(harness)

    def sent() -> int:
        return sum(1 for x in harness.log("fake-g1").splitlines() if x.startswith('{"bad_lowstate'))

    try:
        wait_until(lambda: lows.latest().bad_samples > 0, 5.0)  # type: ignore[union-attr]
        counted, broken = lows.latest().bad_samples, sent()  # type: ignore[union-attr]
        time.sleep(2.0)  # pacing: the window over which both counts grow
        counted, broken = lows.latest().bad_samples - counted, sent() - broken  # type: ignore[union-attr]
        print(f"bad rt/lowstate: {broken} sent, {counted} counted")
        assert broken >= 50 and counted >= 0.8 * broken, (counted, broken)
    finally:
        states.close()
        lows.close()
