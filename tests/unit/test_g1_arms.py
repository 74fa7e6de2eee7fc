"""The G1's rt/arm_sdk stream, pure (fleet/g1/arms.py, injected clock), and Unitree's CRC
(fleet/g1/crc.py) against the SDK's own (unitree_sdk2py utils/crc.py)."""

from __future__ import annotations

import math
import random

import unitree_sdk2py  # noqa: F401 - `make` installs it (--no-deps): a missing SDK fails, never skips
from unitree_sdk2py.idl.default import unitree_hg_msg_dds__LowCmd_, unitree_hg_msg_dds__LowState_
from unitree_sdk2py.utils.crc import CRC

from fleet.g1 import arms
from fleet.g1.config import G1Config, arm_limits, check_g1
from fleet.g1.crc import low_cmd_crc, low_state_crc
from fleet.g1.sim import SimArms

LIMITS = arms.ArmLimits(engage_s=0.5, release_s=3.0, hold_s=3.0)
ZERO = [0.0] * arms.COUNT


def test_crc_is_unitrees() -> None:
    rng = random.Random(23)
    for _ in range(5):
        cmd = unitree_hg_msg_dds__LowCmd_()
        for motor in cmd.motor_cmd:
            motor.mode, motor.q, motor.kp = 1, rng.uniform(-3, 3), rng.uniform(0, 100)
        cmd.reserve = [rng.getrandbits(32) for _ in range(4)]
        assert low_cmd_crc(cmd) == CRC().Crc(cmd)
        state = unitree_hg_msg_dds__LowState_()
        state.tick = rng.getrandbits(32)
        state.imu_state.rpy = [rng.uniform(-1, 1) for _ in range(3)]
        for motor in state.motor_state:
            motor.q, motor.temperature = rng.uniform(-3, 3), [rng.randint(0, 90), 30]
        assert low_state_crc(state) == CRC().Crc(state)


def _run(stream: arms.ArmStream, start_s: float, end_s: float) -> list[tuple[float, list[float]]]:
    out = []
    t = start_s
    while t < end_s:
        step = stream.step(t)
        if step is not None:
            out.append((step[0], list(step[1])))
        t += arms.PERIOD_S
    return out


def _max_step(weights: list[float]) -> float:
    return max(abs(b - a) for a, b in zip(weights, weights[1:], strict=False))


def _known_zero(limits: arms.ArmLimits = LIMITS) -> arms.ArmStream:
    """A stream that knows the robot holds weight 0 (another writer's last message said so)."""
    stream = arms.ArmStream(limits)
    stream.seen(0.0)
    return stream


def test_engage_from_a_known_zero_move_release_never_jump() -> None:
    stream = _known_zero()
    measured = [0.1] * arms.COUNT
    target = [0.3] * arms.COUNT
    stream.set_target(target, 0.5, measured, 0.0)
    up = _run(stream, 0.0, 1.0)
    weights = [w for w, _ in up]
    assert weights[0] <= arms.MAX_WEIGHT_STEP and weights[-1] == 1.0 and stream.phase == "on"
    assert _max_step([0.0, *weights]) <= arms.MAX_WEIGHT_STEP + 1e-9
    assert up[0][1][0] == 0.1 + 0.5 * arms.PERIOD_S  # from the measured pose, rate-limited
    assert stream.q_cmd[0] == 0.3  # reached within 0.4 s at 0.5 rad/s
    assert stream.release("owner") and not stream.release("again")
    down = _run(stream, 1.0, 5.0)
    weights = [w for w, _ in down]
    ramp = [w for w in weights if w > 0]
    assert len(ramp) * arms.PERIOD_S >= arms.MIN_RELEASE_S - 2 * arms.PERIOD_S  # >= 3 s
    assert _max_step([1.0, *weights]) <= arms.PERIOD_S / arms.MIN_RELEASE_S + 1e-9
    assert weights[-arms.TAIL_MESSAGES :] == [0.0] * arms.TAIL_MESSAGES
    assert all(q == [0.3] * arms.COUNT for _, q in down)  # the pose holds while releasing
    assert not stream.active and stream.step(6.0) is None and stream.weight == 0.0


def test_an_unknown_weight_starts_at_1_on_the_measured_pose() -> None:
    """A restarted agent: the robot may still hold a previous stream at any weight. Weight 1 on
    the measured pose is the measured pose whatever it holds (Unitree's example starts so);
    a first message at a small weight would drop the held one at once (issue: 0.90 -> 0.09
    rad in < 100 ms)."""
    stream = arms.ArmStream(LIMITS)
    assert stream.weight is None
    measured = [0.9] * arms.COUNT
    stream.set_target([0.8] * arms.COUNT, 0.5, measured, 0.0)
    first = stream.step(0.0)
    assert first is not None and first[0] == 1.0 and stream.phase == "on"
    assert all(abs(q - 0.9) <= 0.5 * arms.PERIOD_S + 1e-9 for q in first[1])
    # another writer's stream seen at 0.7: not 0, so the same start
    seen = arms.ArmStream(LIMITS)
    seen.seen(0.7)
    seen.set_target(measured, 0.5, measured, 0.0)
    assert seen.step(0.0) == (1.0, measured)


def test_a_release_with_an_unknown_weight_ramps_from_1_on_the_measured_pose() -> None:
    stream = arms.ArmStream(LIMITS)
    assert not stream.release("owner")  # nothing measured: nothing to start from
    held = [0.4] * arms.COUNT
    assert stream.release("owner", held)
    weights = [w for w, q in _run(stream, 0.0, 4.0) if q == held]
    assert weights[0] == 1.0 - stream.down_step and weights[-1] == 0.0
    assert not _known_zero().release("owner", held)  # the robot's own controller has them


def test_a_stop_and_the_lease_hold_by_default() -> None:
    stream = arms.ArmStream(LIMITS)
    stream.set_target(ZERO, 0.5, ZERO, 0.0)
    _run(stream, 0.0, 3.0)
    assert stream.phase == "on"
    held = _run(stream, 3.0, 8.0)
    assert stream.phase == "holding" and "lease" in str(stream.why_held)
    assert {w for w, _ in held} == {1.0} and all(q == ZERO for _, q in held)  # still streamed
    # a stop mid-move freezes the commanded pose where it is, at the weight it had
    moving = _known_zero()
    moving.set_target([0.3] * arms.COUNT, 0.5, ZERO, 0.0)
    _run(moving, 0.0, 0.2)
    weight, pose = moving.weight, list(moving.q_cmd)
    assert moving.interrupt("stopped") and not moving.interrupt("again")
    after = _run(moving, 0.2, 1.0)
    assert all(w == weight and q == pose for w, q in after), (weight, after[:2])
    # a new target (after the reset) goes on from the held pose, no jump
    moving.set_target([0.3] * arms.COUNT, 0.5, [0.9] * arms.COUNT, 1.0)
    step = moving.step(1.0)
    assert step is not None and abs(step[1][0] - pose[0]) <= 0.5 * arms.PERIOD_S + 1e-9


def test_on_stop_release_ramps_down() -> None:
    limits = arms.ArmLimits(engage_s=0.5, hold_s=3.0, on_stop="release")
    stream = arms.ArmStream(limits)
    stream.set_target(ZERO, 0.5, ZERO, 0.0)
    assert stream.interrupt("stopped") and stream.phase == "releasing"


def test_an_fsm_without_arm_sdk_ends_the_stream_and_forgets_the_weight() -> None:
    stream = _known_zero()
    stream.set_target(ZERO, 0.5, ZERO, 0.0)
    _run(stream, 0.0, 1.0)
    assert stream.forget("damping") and stream.weight is None and not stream.active
    assert stream.why_released == "damping"


def test_retarget_mid_release_ramps_up_again_without_a_jump() -> None:
    stream = _known_zero()
    stream.set_target(ZERO, 0.5, ZERO, 0.0)
    weights = [w for w, _ in _run(stream, 0.0, 1.0)]
    stream.release("owner")
    weights += [w for w, _ in _run(stream, 1.0, 1.5)]
    stream.set_target([0.2] * arms.COUNT, 0.5, [0.5] * arms.COUNT, 1.5)
    weights += [w for w, _ in _run(stream, 1.5, 2.5)]
    assert _max_step([0.0, *weights]) <= arms.MAX_WEIGHT_STEP + 1e-9
    assert stream.q_cmd == [0.2] * arms.COUNT  # it kept the commanded pose (weight > 0)


def test_bad_targets_are_refused_with_the_reason() -> None:
    far = [0.0] * arms.COUNT
    far[6] = 1.0
    high = [0.0] * arms.COUNT
    high[1] = 0.6
    nan = [0.0] * arms.COUNT
    nan[0] = math.nan
    cases = [
        ([0.0] * 3, 0.5, "17 (motors 12-28)"),
        (nan, 0.5, "finite"),
        (high, 0.5, "waist_roll (motor 13) 0.6 rad is outside -0.52..0.52"),
        (ZERO, 2.0, "too fast"),
        (far, 0.5, "left_elbow (motor 18) target 1 rad is 1.00 rad from the measured 0"),
    ]
    for q, speed, why in cases:
        assert why in str(arms.target_problem(q, speed, ZERO, LIMITS)), why
    assert "no fresh rt/lowstate" in str(arms.target_problem(ZERO, 0.5, None, LIMITS))
    assert arms.target_problem(ZERO, 0.5, ZERO, LIMITS) is None


def test_sim_blends_by_weight_in_allowed_states_only() -> None:
    from fleet.g1 import idl

    sim = SimArms()
    motors = [idl.MotorCmd_() for _ in range(35)]
    motors[arms.FIRST] = idl.MotorCmd_(1, 1.0, 0, 0, 60, 1.5, 0)
    motors[arms.WEIGHT_INDEX] = idl.MotorCmd_(1, 0.5, 0, 0, 0, 0, 0)
    cmd = idl.LowCmd_(motor_cmd=motors)
    cmd.crc = low_cmd_crc(cmd)
    sim.take(cmd, 500)
    assert sim.pose(500)[arms.FIRST] == 0.5
    sim.take(cmd, 1)  # damping: ignored
    assert sim.ignored == 1
    cmd.crc ^= 1
    sim.take(cmd, 500)
    assert sim.bad == 1
    assert sim.pose(1)[arms.FIRST] == 0.0  # the blending controller is gone


def test_the_inventory_keeps_releases_no_faster_than_unitrees_example() -> None:
    assert check_g1(G1Config(id="h1")) is None
    assert arm_limits(G1Config(id="h1")).on_stop == "hold"
    for too_fast_or_too_slow in (1.0, 6.0):
        why = check_g1(G1Config(id="h1", arm_release_s=too_fast_or_too_slow))
        assert why is not None and "arm_release_s must be within 3..5" in why, why
    assert arm_limits(G1Config(id="h1", arm_on_stop="release")).on_stop == "release"
