"""The contact detector on hand-built traces (exact transitions), the smoothing model, the
coordinator's policy and collision memory, and the simulator's contact faults. No transport."""

from __future__ import annotations

import pytest

from fleet.contact.calibration import Calibration, JointCalibration
from fleet.contact.config import ContactConfig, Thresholds
from fleet.contact.detector import ContactDetector, ContactState
from fleet.contact.dynamics import SIM_DEFAULT
from fleet.coordinator.contact_policy import CollisionMemory, ContactPolicy
from fleet.d1 import protocol as p
from fleet.sim import faults as f
from fleet.sim.model import SimArmModel
from fleet.wire import messages as m

S, C, R, F = (
    ContactState.SUSPECTED,
    ContactState.CONFIRMED,
    ContactState.RELEASED,
    ContactState.FREE,
)


SIM_CALIBRATION = Calibration(
    arm="a1",
    stamp_ns=1,
    joints=[JointCalibration(j, SIM_DEFAULT[0], SIM_DEFAULT[1]) for j in range(7)],
)
"""A calibration that matches the default simulated arm (method 5 trusted)."""


def _only(method: str, calibration: Calibration | None = None, **kw: float) -> ContactDetector:
    config = ContactConfig(methods=[method], arm=Thresholds(**kw))  # type: ignore[list-item,arg-type]
    return ContactDetector(config, calibration=calibration)


def _feed(det: ContactDetector, trace: list[tuple[float, float]], joint: int = 0) -> list:  # type: ignore[type-arg]
    """Feed (time, angle of ``joint``) samples; returns (time, state, method) transitions."""
    out = []
    for t, angle in trace:
        angles = [0.0] * 7
        angles[joint] = angle
        for c in det.on_angles(tuple(angles), t).changes:
            if c.joint == joint:
                out.append((t, c.state, c.method))
    return out


def _hold_then_target(det: ContactDetector, target: float, at: float = 0.05) -> None:
    det.on_targets(dict.fromkeys(range(7), 0.0), 1, 0.0)
    det.on_angles((0.0,) * 7, 0.0)
    det.on_targets({0: target}, None, at)


def test_stall_method_suspects_then_confirms_then_releases_with_hysteresis() -> None:
    # Progress is measured over stall_window_s (0.3 s): the joint stopped at 10 from 0.2 on.
    det = _only("stall", confirm_s=0.15, release_s=0.15)
    _hold_then_target(det, 20.0)
    trace = [(0.1, 5.0), (0.2, 10.0), (0.3, 10.0), (0.4, 10.1), (0.5, 10.1), (0.6, 10.1)]
    trace.append((0.7, 10.1))
    assert _feed(det, trace) == [(0.5, S, "stall"), (0.7, C, "stall")]
    det.on_targets({0: 10.1}, None, 0.75)  # the target retracted: no more error
    later = [(0.8, 10.1), (0.9, 10.1), (1.0, 10.1), (1.1, 10.1), (1.2, 10.1), (1.3, 10.1)]
    assert _feed(det, later) == [(1.0, R, "quiet"), (1.3, F, "quiet")]


def test_suspicion_that_does_not_persist_returns_to_free() -> None:
    # The dead time at the start of a move (0.2 s here) is no stall at all; a joint that then
    # stands still for the whole window is suspected, and free again once it moves.
    det = _only("stall", confirm_s=0.15)
    _hold_then_target(det, 20.0)
    assert _feed(det, [(0.1, 0.0), (0.2, 0.1), (0.3, 12.0)]) == []
    det = _only("stall", confirm_s=0.15)
    _hold_then_target(det, 20.0)
    trace = [(0.1, 0.0), (0.2, 0.0), (0.3, 0.0), (0.4, 0.0), (0.5, 12.0)]
    assert _feed(det, trace) == [(0.4, S, "stall"), (0.5, F, "quiet")]


def test_stall_never_fires_on_a_joint_past_its_target() -> None:
    # A second-order servo overshoots and stands still at the peak: not a contact.
    det = _only("stall", confirm_s=0.0)
    _hold_then_target(det, 20.0)
    trace = [(0.1, 10.0), (0.2, 26.0), (0.3, 26.0), (0.4, 26.0), (0.5, 26.0), (0.6, 26.0)]
    assert _feed(det, trace) == []


def test_tracking_method_confirms_on_a_large_step_alone() -> None:
    # Method 1 alone cannot tell a slow commanded step from a contact: the benchmark's point.
    det = _only("tracking", confirm_s=0.15)
    _hold_then_target(det, 60.0)
    assert _feed(det, [(0.1, 10.0), (0.2, 25.0), (0.3, 40.0)]) == [
        (0.1, S, "tracking"),
        (0.3, C, "tracking"),
    ]


def test_model_method_quiet_while_the_joint_follows_the_model() -> None:
    det = _only("model", SIM_CALIBRATION, confirm_s=0.05)
    _hold_then_target(det, 60.0)
    model = SimArmModel()
    model.apply(p.encode_command(p.SetJointAngle(0, 60.0), 1))
    trace = []
    for k in range(1, 15):
        model.advance(k * 0.1 - 0.05)  # the model started at 0.05, like the target
        trace.append((k * 0.1, model.angles_deg[0]))
    assert _feed(det, trace) == []


def test_model_method_confirms_when_the_joint_stops_short() -> None:
    det = _only("model", SIM_CALIBRATION, confirm_s=0.05)
    _hold_then_target(det, 60.0)
    # At 0.1 the model expects 4.5 deg (speed limit), within 1 + 90 deg/s * 0.04 s of 1.0.
    # At 0.2 it is more than two tolerances behind: one sample confirms (a trusted model).
    changes = _feed(det, [(0.1, 1.0), (0.2, 1.0), (0.3, 1.0)])
    assert changes == [(0.2, S, "model"), (0.2, C, "model")]


def test_status_method_confirms_at_once_on_the_joint_furthest_off() -> None:
    det = _only("status")
    det.on_targets(dict.fromkeys(range(7), 0.0), 1, 0.0)
    det.on_angles((0.0,) * 7, 0.0)
    det.on_targets({2: 30.0}, None, 0.05)
    det.on_status(True, True, True, 0.08)
    assert _feed(det, [(0.1, 10.0)], joint=2) == [(0.1, C, "status")]


def test_oscillation_method_needs_reversals_under_a_steady_target() -> None:
    det = _only("oscillation", oscillation_reversals=4, confirm_s=0.0)
    _hold_then_target(det, 10.0, at=0.0)
    # (errors of 4-5 deg: the joint stays short of its target, so it is no ringing about it)
    trace = [(0.1 * k, 5.0 + (1.0 if k % 2 else 0.0)) for k in range(1, 9)]
    # steps +6 (leaving 0), -1, +1, -1, +1: the fourth reversal is at 0.5
    assert _feed(det, trace) == [(0.5, S, "oscillation"), (0.5, C, "oscillation")]


def test_unloaded_joint_moved_by_hand_is_never_a_contact() -> None:
    det = ContactDetector(ContactConfig())
    _hold_then_target(det, 0.0)
    det.on_torque(0, False)
    assert _feed(det, [(0.1 * k, 3.0 * k) for k in range(1, 20)]) == []


def test_gripper_closing_on_an_object_is_a_grip() -> None:
    det = ContactDetector(ContactConfig())
    det.on_targets(dict.fromkeys(range(7), 0.0) | {6: 60.0}, 1, 0.0)
    det.on_angles((0.0,) * 6 + (60.0,), 0.0)
    det.on_targets({6: 0.0}, None, 0.05)
    grips = []
    for k in range(1, 10):
        angle = max(20.0, 60.0 - 9.0 * k)  # stopped by the object at 20
        for c in det.on_angles((0.0,) * 6 + (angle,), 0.1 * k).changes:
            grips.append((c.state, c.grip))
    assert (C, True) in grips


def test_a_gripper_that_closes_upwards_grips_when_it_rises_onto_an_object() -> None:
    """An arm whose ``angle6`` reads 100 closed and 0 open (``gripper_closing_sign`` +1): its
    closing is a rising angle, and the contact that stops it is a grip; the same motion on a
    default arm (0 closed) is opening, never a grip."""
    for sign, expect_grip in ((1.0, True), (-1.0, False)):
        det = ContactDetector(ContactConfig(), gripper_closing_sign=sign)
        det.on_targets(dict.fromkeys(range(7), 0.0) | {6: 5.0}, 1, 0.0)
        det.on_angles((0.0,) * 6 + (5.0,), 0.0)
        det.on_targets({6: 60.0}, None, 0.05)
        confirmed = []
        for k in range(1, 10):
            angle = min(40.0, 5.0 + 9.0 * k)  # stopped by the object at 40
            for c in det.on_angles((0.0,) * 6 + (angle,), 0.1 * k).changes:
                if c.state is C:
                    confirmed.append(c.grip)
        assert confirmed and all(g is expect_grip for g in confirmed), (sign, confirmed)


def _event(joint: int, commanded: bool, state: str = "confirmed") -> m.ContactEvent:
    return m.ContactEvent(
        stamp_ns=1,
        joint=joint,
        state=state,  # type: ignore[arg-type]
        method="model",
        error_deg=10.0,
        confidence=0.5,
        target_deg=40.0,
        measured_deg=20.0,
        commanded=commanded,
        grip=joint == 6,
    )


def test_policy_stops_idle_and_lifting_arms_backs_off_once_while_moving() -> None:
    policy = ContactPolicy()
    assert [a.kind for a in policy.on_event("a1", _event(1, commanded=False), 0.0)] == ["estop"]
    policy.set_phase("a1", "lift", 0.0)
    assert [a.kind for a in policy.on_event("a1", _event(1, True), 1.0)] == ["estop"]
    first = policy.on_event("a2", _event(1, True), 2.0)[0]
    assert first.kind == "backoff_retry" and first.backoff_deg == 15.0 and first.retry_deg == 40.0
    assert policy.on_event("a2", _event(1, True), 3.0)[0].kind == "hold"
    assert policy.on_event("a2", _event(6, True), 3.0)[0].kind == "report"
    assert policy.on_event("a2", _event(2, True, "suspected"), 3.0) == []
    assert policy.in_contact("a2")


def test_collision_memory_avoids_after_repeats_expires_and_clears() -> None:
    memory = CollisionMemory(place_deg=3.0, expire_s=60.0, avoid_after=3)
    for t in (0.0, 1.0):
        memory.record("a1", 1, 20.0, +1, t)
    assert memory.avoided("a1", 1, 40.0, 2.0) is None  # two contacts: not yet avoided
    assert memory.record("a1", 1, 21.0, +1, 2.0) == 3
    assert memory.avoided("a1", 1, 40.0, 3.0) == 20.0
    assert memory.avoided("a1", 1, 5.0, 3.0) is None  # moving away is fine
    assert memory.avoided("a1", 1, 40.0, 61.5) is None  # two of three expired
    memory.record("a1", 1, 20.0, +1, 70.0)
    memory.clear()
    assert memory.avoided("a1", 1, 40.0, 70.0) is None


def test_sim_obstacle_is_compliant_and_hunting_and_grip_object_stops_the_gripper() -> None:
    model = SimArmModel()
    f.apply_fault(model.faults, f.AddObstacle(joint=0, angle_deg=20.0, compliance=0.1))
    f.apply_fault(model.faults, f.GripObject(width_deg=25.0))
    model.apply(p.encode_command(p.SetAllAngles((60.0, 0, 0, 0, 0, 0, 0.0), 0), 1))
    model.target_deg[6] = 0.0
    model.angles_deg[6] = 50.0
    model.advance(3.0)
    assert model.angles_deg[0] == pytest.approx(24.0, abs=0.01)  # 20 + 0.1 * (60 - 20)
    assert model.angles_deg[6] == pytest.approx(25.0 - 0.05 * 25.0, abs=0.01)
    f.apply_fault(model.faults, f.AddObstacle(joint=0, angle_deg=20.0, hunting_deg=1.0))
    seen = set()
    for k in range(1, 30):
        model.advance(3.0 + 0.033 * k)
        seen.add(round(model.angles_deg[0], 1))
    assert len(seen) > 5  # hunting moves it about
    f.apply_fault(model.faults, f.Noise(noise_deg=0.1))
    reports = {model.joint_report() for _ in range(5)}
    assert len(reports) == 5  # noisy, seeded


def test_oscillation_ignores_a_servo_ringing_about_its_target() -> None:
    # A second-order servo overshoots 4 deg and rings across its target: no hunting.
    det = _only("oscillation", oscillation_reversals=4, confirm_s=0.0)
    _hold_then_target(det, 10.0, at=0.0)
    trace = [(0.1 * k, 10.0 + (4.0 if k % 2 else -4.0)) for k in range(1, 9)]
    assert _feed(det, trace) == []
