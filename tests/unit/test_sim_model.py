"""The simulated arm's pure model, driven with injected time: physics, quirks and faults."""

from __future__ import annotations

import pytest

from fleet.d1 import protocol as p
from fleet.sim import faults as f
from fleet.sim.model import SMOOTHING, Faults, SimArmModel

ZERO = (0.0,) * 7


def _send(model: SimArmModel, command: p.Command, seq: int = 1) -> list[p.ArmMessage]:
    return model.apply(p.encode_command(command, seq))


def _ok_acks(seq: int) -> list[p.ArmMessage]:
    return [p.ReceiveAck(seq, True), p.ExecuteAck(seq, True)]


def _target(joint: int, angle: float) -> tuple[float, ...]:
    angles = list(ZERO)
    angles[joint] = angle
    return tuple(angles)


def _run(model: SimArmModel, until_s: float, step_s: float = 0.01) -> list[list[float]]:
    """Advance in ``step_s`` steps, returning the angles after each step."""
    trace = []
    t = model.time_s
    while t < until_s - 1e-9:
        t = min(until_s, t + step_s)
        model.advance(t)
        trace.append(list(model.angles_deg))
    return trace


def test_commands_are_acknowledged_with_their_seq() -> None:
    model = SimArmModel()
    assert _send(model, p.SetAllAngles(_target(0, 30.0), mode=0), seq=7) == _ok_acks(7)
    assert _send(model, p.ReturnToZero(), seq=8) == _ok_acks(8)


def test_mode_1_is_slower_than_mode_0() -> None:
    fast, slow = SimArmModel(), SimArmModel()
    _send(fast, p.SetAllAngles(_target(1, 60.0), mode=0))
    _send(slow, p.SetAllAngles(_target(1, 60.0), mode=1))
    for t in (0.1, 0.2, 0.3, 0.5):
        fast.advance(t)
        slow.advance(t)
        assert fast.angles_deg[1] > slow.angles_deg[1] + 1.0, t
    fast.advance(1.0)
    slow.advance(3.0)
    assert fast.angles_deg[1] == pytest.approx(60.0, abs=0.5)
    assert slow.angles_deg[1] == pytest.approx(60.0, abs=0.5)


@pytest.mark.parametrize("mode", [0, 1])
def test_speed_limit_is_respected(mode: int) -> None:
    _tau, vmax = SMOOTHING[mode]
    model = SimArmModel()
    _send(model, p.SetAllAngles((135.0, -90.0, 90.0, -135.0, 90.0, 135.0, 65.0), mode=mode))
    step = 0.01
    previous = list(model.angles_deg)
    for angles in _run(model, 2.0, step):
        for joint in range(7):
            assert abs(angles[joint] - previous[joint]) <= vmax * step + 1e-9
        previous = angles
    # ... also over one long advance, which integrates in small steps
    model = SimArmModel()
    _send(model, p.SetAllAngles(_target(0, 135.0), mode=mode))
    model.advance(0.5)
    assert 0.0 < model.angles_deg[0] <= vmax * 0.5 + 1e-9


def test_time_never_runs_backwards() -> None:
    model = SimArmModel()
    _send(model, p.SetJointAngle(0, 50.0))
    model.advance(0.4)
    angle = model.angles_deg[0]
    model.advance(0.2)
    model.advance(0.4)
    assert model.angles_deg[0] == angle
    assert model.time_s == 0.4


def test_unloaded_joint_does_not_track() -> None:
    model = SimArmModel()
    assert _send(model, p.SetJointTorque(2, False)) == _ok_acks(1)
    _send(model, p.SetAllAngles((10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 10.0), mode=0), seq=2)
    model.advance(2.0)
    assert model.angles_deg[2] == 0.0
    assert all(model.angles_deg[j] == pytest.approx(10.0, abs=0.1) for j in (0, 1, 3, 4, 5, 6))


def test_all_unloaded_arm_does_not_track_and_reports_disabled() -> None:
    model = SimArmModel()
    _send(model, p.SetAllTorque(0))
    _send(model, p.SetJointAngle(0, 45.0), seq=2)
    model.advance(2.0)
    assert model.angles_deg == list(ZERO)
    status = model.status_reports()[0]
    assert status == p.D1Status(enabled=False, powered=True, error_status=1)
    _send(model, p.SetAllTorque(80000), seq=3)
    assert model.enabled == [True] * 7


def test_powered_off_arm_does_not_track_and_fails_motion() -> None:
    model = SimArmModel()
    _send(model, p.SetAllAngles(_target(0, 60.0), mode=0))
    model.advance(0.1)
    assert _send(model, p.SetPower(False), seq=2) == _ok_acks(2)
    frozen = list(model.angles_deg)
    assert 0.0 < frozen[0] < 60.0
    model.advance(2.0)
    assert model.angles_deg == frozen
    # motion commands are received but not executed while the power is off
    assert _send(model, p.SetJointAngle(1, 20.0), seq=3) == [
        p.ReceiveAck(3, True),
        p.ExecuteAck(3, False),
    ]
    assert model.status_reports()[0] == p.D1Status(enabled=True, powered=False, error_status=1)


def test_reenabled_joint_chases_its_old_cached_target() -> None:
    # Field-reported quirk: while a joint is unloaded it keeps the target it was given; when it
    # is enabled again it moves there (so the agent holds the measured pose before enabling).
    model = SimArmModel()
    _send(model, p.SetJointTorque(1, False), seq=1)
    _send(model, p.SetJointAngle(1, 40.0), seq=2)
    model.advance(2.0)
    assert model.angles_deg[1] == 0.0
    _send(model, p.SetJointTorque(1, True), seq=3)
    model.advance(5.0)
    assert model.angles_deg[1] == pytest.approx(40.0, abs=0.1)


def test_hold_before_enable_keeps_the_joint_still() -> None:
    model = SimArmModel()
    _send(model, p.SetJointTorque(1, False), seq=1)
    _send(model, p.SetJointAngle(1, 40.0), seq=2)
    model.advance(1.0)
    _send(model, p.SetAllAngles(tuple(model.angles_deg), mode=0), seq=3)  # what the agent does
    _send(model, p.SetJointTorque(1, True), seq=4)
    model.advance(3.0)
    assert model.angles_deg[1] == 0.0


def test_invalid_joint_id_is_acked_then_the_angle_feed_stops() -> None:
    model = SimArmModel()
    assert model.joint_report() == p.JointAngles(ZERO)
    text = '{"seq":21,"address":1,"funcode":1,"data":{"id":9,"angle":10,"delay_ms":0}}'
    assert model.apply(text) == [p.ReceiveAck(21, True), p.ExecuteAck(21, False)]
    assert model.angle_feed_stopped
    assert model.joint_report() is None
    assert len(model.status_reports()) == 2  # status keeps coming
    _send(model, p.ReturnToZero(), seq=22)
    assert model.joint_report() is None  # and the feed stays off


def test_invalid_torque_joint_id_also_stops_the_feed() -> None:
    model = SimArmModel()
    text = '{"seq":5,"address":1,"funcode":4,"data":{"id":7,"mode":1}}'
    assert model.apply(text) == [p.ReceiveAck(5, True), p.ExecuteAck(5, False)]
    assert model.joint_report() is None


def test_out_of_range_and_malformed_commands_get_recv_status_0() -> None:
    model = SimArmModel()
    text = '{"seq":31,"address":1,"funcode":1,"data":{"id":1,"angle":120,"delay_ms":0}}'
    assert model.apply(text) == [p.ReceiveAck(31, False)]
    assert model.apply('{"seq":32,"address":1,"funcode":6,"data":{"power":7}}') == [
        p.ReceiveAck(32, False)
    ]
    assert model.apply('{"seq":33,"address":1,"funcode":9}') == [p.ReceiveAck(33, False)]
    assert model.apply("garbage") == []  # no seq to answer
    assert model.target_deg == list(ZERO)
    assert not model.angle_feed_stopped


def test_stall_holds_the_joint_at_the_obstacle() -> None:
    model = SimArmModel()
    model.faults.stalls[0] = 20.0
    _send(model, p.SetAllAngles(_target(0, 60.0), mode=0))
    model.advance(3.0)
    assert model.angles_deg[0] == 20.0
    # from the other side, moving down: stops at the obstacle too
    model.faults.stalls[3] = -15.0
    _send(model, p.SetAllAngles((20.0, 0.0, 0.0, -60.0, 0.0, 0.0, 0.0), mode=0), seq=2)
    model.advance(6.0)
    assert model.angles_deg[3] == -15.0
    # it can move away from the obstacle, and on once it is removed
    _send(model, p.SetJointAngle(0, 5.0), seq=3)
    model.advance(8.0)
    assert model.angles_deg[0] == pytest.approx(5.0, abs=0.1)
    f.apply_fault(model.faults, f.Unstall(joint=3))
    model.advance(11.0)
    assert model.angles_deg[3] == pytest.approx(-60.0, abs=0.1)


def test_same_stall_again_from_the_other_side() -> None:
    model = SimArmModel()
    f.apply_fault(model.faults, f.Stall(joint=0, angle_deg=20.0))
    _send(model, p.SetJointAngle(0, 60.0))
    model.advance(3.0)
    assert model.angles_deg[0] == 20.0
    f.apply_fault(model.faults, f.Unstall(joint=0))
    model.advance(6.0)
    assert model.angles_deg[0] == pytest.approx(60.0, abs=0.1)
    f.apply_fault(model.faults, f.Stall(joint=0, angle_deg=20.0))
    _send(model, p.SetJointAngle(0, -60.0), seq=2)
    model.advance(9.0)
    assert model.angles_deg[0] == 20.0


def test_motor_offline_does_not_move_and_is_reported() -> None:
    model = SimArmModel()
    f.apply_fault(model.faults, f.MotorOffline(joint=3))
    _send(model, p.SetAllAngles((10.0,) * 7, mode=0))
    model.advance(2.0)
    assert model.angles_deg[3] == 0.0
    assert model.angles_deg[2] == pytest.approx(10.0, abs=0.1)
    motors = model.status_reports()[1]
    assert motors == p.MotorStatus((True, True, True, False, True, True, True))
    f.apply_fault(model.faults, f.MotorOffline(joint=3, offline=False))
    model.advance(4.0)
    assert model.angles_deg[3] == pytest.approx(10.0, abs=0.1)


def test_mute_acks_executes_without_acknowledging() -> None:
    model = SimArmModel()
    f.apply_fault(model.faults, f.MuteAcks(on=True))
    assert _send(model, p.SetJointAngle(0, 30.0), seq=4) == []
    assert model.apply('{"seq":5,"address":1,"funcode":6,"data":{"power":7}}') == []
    model.advance(2.0)
    assert model.angles_deg[0] == pytest.approx(30.0, abs=0.1)
    f.apply_fault(model.faults, f.MuteAcks(on=False))
    assert _send(model, p.SetJointAngle(0, 0.0), seq=6) == _ok_acks(6)


def test_error_status_is_reported() -> None:
    model = SimArmModel()
    f.apply_fault(model.faults, f.ErrorStatus(error=True))
    assert model.status_reports()[0] == p.D1Status(enabled=True, powered=True, error_status=0)
    text = p.encode_message(model.status_reports()[0])
    assert '"error_status":0' in text


def test_drop_feedback_silences_every_report() -> None:
    model = SimArmModel()
    f.apply_fault(model.faults, f.DropFeedback(on=True))
    assert model.joint_report() is None
    assert model.status_reports() == []
    assert _send(model, p.ReturnToZero()) == _ok_acks(1)  # acks are not feedback reports
    f.apply_fault(model.faults, f.ClearFaults())
    assert model.joint_report() == p.JointAngles(ZERO)


def test_joint_report_is_rounded_and_encodable() -> None:
    model = SimArmModel()
    _send(model, p.SetAllAngles((33.3333, -12.3456, 1.0, 0.0, 0.0, 0.0, 5.0), mode=0))
    model.advance(0.137)
    report = model.joint_report()
    assert report is not None
    assert all(round(a, 2) == a for a in report.angles_deg)
    assert p.decode_message(p.encode_message(report)).message == report


def test_return_to_zero_uses_large_smoothing() -> None:
    model = SimArmModel()
    _send(model, p.SetAllAngles(_target(0, 60.0), mode=0))
    model.advance(2.0)
    _send(model, p.ReturnToZero(), seq=2)
    assert model.mode == 1
    assert model.target_deg == list(ZERO)
    model.advance(6.0)
    assert model.angles_deg[0] == pytest.approx(0.0, abs=0.1)


def test_fault_requests_decode_and_apply() -> None:
    faults = Faults()
    for payload in (
        b'{"op":"stall","joint":2,"angle_deg":15.5}',
        b'{"op":"motor_offline","joint":4}',
        b'{"op":"error_status"}',
        b'{"op":"drop_feedback","on":true}',
        b'{"op":"mute_acks","on":true}',
    ):
        f.apply_fault(faults, f.FAULT.decode(payload))
    assert faults == Faults(
        stalls={2: 15.5},
        motors_offline={4},
        error_status=True,
        drop_feedback=True,
        mute_acks=True,
    )
    f.apply_fault(faults, f.FAULT.decode(b'{"op":"clear"}'))
    assert faults == Faults()


@pytest.mark.parametrize("joint", [-1, 7])
def test_fault_on_a_bad_joint_is_refused(joint: int) -> None:
    with pytest.raises(ValueError, match="outside 0..6"):
        f.apply_fault(Faults(), f.Stall(joint=joint, angle_deg=0.0))


def test_an_arm_at_rest_skips_the_integration_and_stays_exactly() -> None:
    """The at-rest shortcut (no stepping) gives what stepping gives: the same angles, the
    time moved on; a command ends it, and a stall keeps the arm on the stepped path."""
    arm = SimArmModel(time_s=0.0)
    arm.advance(5.0)
    assert arm.angles_deg == [0.0] * 7 and arm.time_s == 5.0
    arm.apply('{"seq":4,"address":1,"funcode":1,"data":{"id":0,"angle":30}}')
    arm.advance(6.0)
    assert 0.0 < arm.angles_deg[0] <= 30.0
    arm.faults.stalls[1] = 0.0
    assert not arm._at_rest()
