"""The edge agent's pure logic with injected times: command planning, in-flight bookkeeping and
the per-arm tracker (link state, counters). No DDS, no Zenoh."""

from __future__ import annotations

import math

import pytest

from fleet.d1 import protocol as p
from fleet.d1arm.commands import InFlight, Plan, plan
from fleet.d1arm.holds import clamp_to_limits
from fleet.d1arm.tracker import ArmTracker
from fleet.devices.driver import Refusal
from fleet.inventory import ArmConfig
from fleet.origin.trust import SampleWriter
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode

HOME = (0.0, -10.0, 20.0, 0.0, 30.0, 0.0, 5.0)


def _feedback(angles: tuple[float, ...] = HOME) -> str:
    return p.encode_message(p.JointAngles(angles))


def _tracker(
    *,
    angles: tuple[float, ...] | None = HOME,
    powered: bool | None = True,
    estopped: bool = False,
    config: ArmConfig | None = None,
) -> ArmTracker:
    """A tracker whose link is ok at t=0 (fed one angle report), unless ``angles`` is None."""
    tracker = ArmTracker(config or ArmConfig(id="a1"))
    if angles is not None:
        tracker.on_feedback(_feedback(angles), now=0.0)
        tracker.update_link(0.0)
    tracker.powered = powered
    if estopped:
        tracker.safety.latch(
            "test-stop", "test", "", now_s=0.0, now_ns=0, action=tracker.config.stop_action
        )
    return tracker


def _refused(command: m.ArmCommand, tracker: ArmTracker) -> Refusal:
    with pytest.raises(Refusal) as info:
        plan(command, tracker, now=0.0)
    return info.value


# ----------------------------------------------------------------------------- plan


def test_move_joint_plans_one_command_and_its_target() -> None:
    result = plan(m.MoveJoint(joint=2, angle_deg=-45.5), _tracker(), now=0.0)
    assert result == Plan((p.SetJointAngle(2, -45.5),), {2: -45.5})


def test_move_joints_plans_all_angles() -> None:
    target = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    result = plan(m.MoveJoints(angles_deg=target, mode=0), _tracker(), now=0.0)
    assert result.commands == (p.SetAllAngles(tuple(target), 0),)
    assert result.targets_deg == dict(enumerate(target))


def test_zero_plans_return_to_zero() -> None:
    result = plan(m.Zero(), _tracker(), now=0.0)
    assert result.commands == (p.ReturnToZero(),)
    assert result.targets_deg == dict.fromkeys(range(7), 0.0)


def test_power_plans_set_power() -> None:
    assert plan(m.Power(on=False), _tracker(), now=0.0).commands == (p.SetPower(False),)
    assert plan(m.Power(on=True), _tracker(powered=False), now=0.0).commands == (p.SetPower(True),)


MOTIONS = [
    m.MoveJoint(joint=0, angle_deg=10.0),
    m.MoveJoints(angles_deg=[0.0] * 7),
    m.Zero(),
]


@pytest.mark.parametrize("command", MOTIONS)
def test_motion_refused_while_estopped(command: m.ArmCommand) -> None:
    error = _refused(command, _tracker(estopped=True))
    assert error.code == ErrorCode.REJECTED == 4002
    assert "stopped" in str(error) and "fleet reset a1" in str(error)


@pytest.mark.parametrize("command", MOTIONS)
def test_motion_refused_when_link_is_not_ok(command: m.ArmCommand) -> None:
    tracker = _tracker()
    tracker.update_link(1.0)  # 1 s without feedback: stale
    assert tracker.link == "stale"
    error = _refused(command, tracker)
    assert error.code == ErrorCode.REJECTED
    assert "link stale" in str(error)
    never = _tracker(angles=None)  # never heard from the arm: lost
    assert _refused(command, never).code == ErrorCode.REJECTED


@pytest.mark.parametrize("command", MOTIONS)
def test_motion_refused_while_powered_off(command: m.ArmCommand) -> None:
    error = _refused(command, _tracker(powered=False))
    assert error.code == ErrorCode.REJECTED
    assert "powered off" in str(error)


def test_motion_allowed_while_power_state_unknown() -> None:
    assert plan(m.Zero(), _tracker(powered=None), now=0.0).commands == (p.ReturnToZero(),)


@pytest.mark.parametrize(
    "command",
    [
        m.MoveJoint(joint=0, angle_deg=135.01),
        m.MoveJoint(joint=1, angle_deg=-90.5),
        m.MoveJoint(joint=6, angle_deg=65.1),
        m.MoveJoint(joint=6, angle_deg=-1.0),
        m.MoveJoint(joint=7, angle_deg=0.0),
        m.MoveJoint(joint=-1, angle_deg=0.0),
        m.MoveJoint(joint=0, angle_deg=math.nan),
        m.MoveJoint(joint=0, angle_deg=math.inf),
        m.MoveJoints(angles_deg=[0.0, 0.0, 95.0, 0.0, 0.0, 0.0, 0.0]),
        m.MoveJoints(angles_deg=[0.0] * 6),
        m.MoveJoints(angles_deg=[0.0] * 8),
        m.MoveJoints(angles_deg=[0.0] * 6 + [math.nan]),
        m.Torque(on=True, joint=7),
        m.Torque(on=False, joint=-1),
        m.Torque(on=True, strength=80001),
        m.Torque(on=True, strength=-1),
        m.Torque(on=True, joint=2, strength=100),
    ],
)
def test_out_of_range_is_a_parameter_error(command: m.ArmCommand) -> None:
    error = _refused(command, _tracker())
    assert error.code == ErrorCode.PARAMETER == 3204


def test_out_of_range_is_a_parameter_error_in_any_state() -> None:
    # 3204 says what is wrong with the command itself, whatever the arm's state.
    bad = m.MoveJoint(joint=1, angle_deg=120.0)
    for tracker in (_tracker(estopped=True), _tracker(angles=None), _tracker(powered=False)):
        assert _refused(bad, tracker).code == ErrorCode.PARAMETER


def test_limits_are_inclusive() -> None:
    plan(
        m.MoveJoints(angles_deg=[135.0, -90.0, 90.0, -135.0, 90.0, 135.0, 65.0]),
        _tracker(),
        now=0.0,
    )
    plan(m.MoveJoint(joint=6, angle_deg=0.0), _tracker(), now=0.0)


def test_torque_on_holds_the_measured_pose_first() -> None:
    # A re-enabled D1 chases its old cached target: the plan makes the measured pose the target.
    result = plan(m.Torque(on=True), _tracker(), now=0.0)
    assert result.commands == (p.SetAllAngles(HOME, 0), p.SetAllTorque(1))
    result = plan(m.Torque(on=True, joint=3), _tracker(), now=0.0)
    assert result.commands == (p.SetAllAngles(HOME, 0), p.SetJointTorque(3, True))
    result = plan(m.Torque(on=True, strength=80000), _tracker(), now=0.0)
    assert result.commands == (p.SetAllAngles(HOME, 0), p.SetAllTorque(80000))
    assert result.targets_deg == {}


def test_torque_on_needs_measured_angles_and_no_stop() -> None:
    assert _refused(m.Torque(on=True), _tracker(angles=None)).code == ErrorCode.REJECTED
    assert _refused(m.Torque(on=True), _tracker(estopped=True)).code == ErrorCode.REJECTED


def test_torque_off_and_power_off_are_refused_while_a_hold_stop_is_latched() -> None:
    # The stop holds the arm up: unloading or powering it off would let it fall.
    for command in (m.Torque(on=False), m.Torque(on=False, joint=4), m.Power(on=False)):
        refused = _refused(command, _tracker(estopped=True))
        assert refused.code == ErrorCode.REJECTED and "fall" in str(refused)


def test_torque_off_and_power_off_are_allowed_while_an_unload_stop_is_latched() -> None:
    for action in ("unload", "power_off"):
        config = ArmConfig(id="a1", stop_action=action)  # type: ignore[arg-type]
        tracker = _tracker(estopped=True, config=config)
        assert plan(m.Torque(on=False), tracker, now=0.0).commands == (p.SetAllTorque(0),)
        result = plan(m.Torque(on=False, joint=4), tracker, now=0.0)
        assert result.commands == (p.SetJointTorque(4, False),)
        assert plan(m.Power(on=False), tracker, now=0.0).commands == (p.SetPower(False),)


def test_power_on_and_torque_on_refused_while_stopped() -> None:
    assert _refused(m.Power(on=True), _tracker(estopped=True)).code == ErrorCode.REJECTED
    assert _refused(m.Torque(on=True), _tracker(estopped=True)).code == ErrorCode.REJECTED


def test_hold_refuses_a_start_time_and_a_stale_pose() -> None:
    later = m.Hold(start_at_ns=1)
    assert _refused(later, _tracker()).code == ErrorCode.PARAMETER
    tracker = _tracker()
    stale_s = tracker.config.link_stale_s + 0.01
    with pytest.raises(Refusal) as info:
        plan(m.Hold(), tracker, now=stale_s)
    assert info.value.code == ErrorCode.REJECTED and "fresh" in str(info.value)


def test_hold_uses_the_measured_pose_clamped_to_the_limits() -> None:
    measured = (135.4, -90.2, 0.0, 0.0, 0.0, 0.0, -0.3)
    result = plan(m.Hold(), _tracker(angles=measured, estopped=True), now=0.0)
    held = (135.0, -90.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert result.commands == (p.SetAllAngles(held, 0),)
    assert result.targets_deg == dict(enumerate(held))
    assert _refused(m.Hold(), _tracker(angles=None)).code == ErrorCode.REJECTED


def test_clamp_to_limits() -> None:
    assert clamp_to_limits((200.0, -200.0, 0.0, 1.0, 2.0, 3.0, 70.0)) == (
        135.0,
        -90.0,
        0.0,
        1.0,
        2.0,
        3.0,
        65.0,
    )


def test_every_planned_command_encodes() -> None:
    tracker = _tracker()
    for command in [
        *MOTIONS,
        m.Hold(),
        m.Torque(on=True),
        m.Torque(on=False),
        m.Power(on=True),
        m.MoveJoint(joint=6, angle_deg=65.0),
    ]:
        for d1 in plan(command, tracker, now=0.0).commands:
            p.decode_command(p.encode_command(d1, 1))


# ----------------------------------------------------------------------------- InFlight


def _flight(seqs: tuple[int, ...] = (5,), wait_reached: bool = False, **kw: object) -> InFlight:
    args: dict[str, object] = {
        "arm": "a1",
        "seqs": seqs,
        "started_s": 100.0,
        "recv_deadline_s": 100.5,
        "exec_deadline_s": 102.0,
        "reach_deadline_s": 110.0 if wait_reached else None,
        "targets_deg": {0: 30.0, 1: -20.0},
        "tolerance_deg": 2.0,
        "written_ns": 1,  # written to DDS (a delayed start is not, until its time)
    }
    args.update(kw)
    return InFlight(**args)  # type: ignore[arg-type]


def test_acks_complete_a_command() -> None:
    flight = _flight()
    flight.on_time(100.1, None)
    assert not flight.done
    flight.on_ack(p.ReceiveAck(5, True))
    assert not flight.done
    flight.on_ack(p.ExecuteAck(5, True))
    assert flight.done
    reply = flight.reply(100.25)
    assert reply.ok and reply.error is None
    assert (reply.arm, reply.seq, reply.received, reply.executed) == ("a1", 5, True, True)
    assert reply.reached is None
    assert reply.latency_ms == pytest.approx(250.0)


def test_two_commands_need_both_acks() -> None:
    flight = _flight(seqs=(5, 6))
    for ack in (p.ReceiveAck(5, True), p.ExecuteAck(5, True), p.ReceiveAck(6, True)):
        flight.on_ack(ack)
        assert not flight.done
    flight.on_ack(p.ExecuteAck(6, True))
    assert flight.done
    assert flight.reply(101.0).seq == 6


def test_no_receive_ack_times_out_with_3104() -> None:
    flight = _flight()
    flight.on_time(100.49, None)
    assert not flight.done
    flight.on_time(100.5, None)
    assert flight.done
    reply = flight.reply(100.5)
    assert not reply.ok
    assert reply.error is not None and reply.error.code == ErrorCode.TIMEOUT == 3104
    assert "no receive ack" in reply.error.message and "'a1'" in reply.error.message
    assert (reply.received, reply.executed) == (False, False)


def test_no_execute_ack_times_out_with_3104() -> None:
    flight = _flight()
    flight.on_ack(p.ReceiveAck(5, True))
    flight.on_time(101.0, None)  # past the receive deadline, but received: fine
    assert not flight.done
    flight.on_time(102.0, None)
    reply = flight.reply(102.0)
    assert reply.error is not None and reply.error.code == ErrorCode.TIMEOUT
    assert "no execute ack" in reply.error.message
    assert reply.received is True


def test_recv_status_0_fails_the_command() -> None:
    flight = _flight()
    flight.on_ack(p.ReceiveAck(5, False))
    assert flight.done
    reply = flight.reply(100.1)
    assert not reply.ok
    assert reply.error is not None and reply.error.code == ErrorCode.ARM_REFUSED == 4007
    assert "recv_status 0" in reply.error.message


def test_exec_status_0_fails_the_command() -> None:
    flight = _flight()
    flight.on_ack(p.ReceiveAck(5, True))
    flight.on_ack(p.ExecuteAck(5, False))
    reply = flight.reply(100.1)
    assert reply.error is not None and reply.error.code == ErrorCode.ARM_FAILED == 4008
    assert "exec_status 0" in reply.error.message


def test_first_error_wins() -> None:
    flight = _flight()
    flight.on_ack(p.ReceiveAck(5, False))
    flight.on_time(200.0, None)
    assert flight.error is not None and flight.error.code == ErrorCode.ARM_REFUSED


def test_reached_completes_a_wait_reached_command() -> None:
    flight = _flight(wait_reached=True)
    flight.on_ack(p.ReceiveAck(5, True))
    flight.on_ack(p.ExecuteAck(5, True))
    assert not flight.done  # acked, but the target is not reached yet
    flight.on_angles((10.0, -20.0, 0, 0, 0, 0, 0))
    assert not flight.done
    flight.on_time(105.0, (10.0, -20.0, 0, 0, 0, 0, 0))
    assert not flight.done  # the acks' deadlines do not apply while waiting for the target
    flight.on_angles((28.5, -21.9, 99.0, 0, 0, 0, 0))  # within 2 deg on joints 0 and 1
    assert flight.done
    reply = flight.reply(106.0)
    assert reply.ok and reply.reached is True


def test_a_command_not_yet_written_is_never_reached() -> None:
    flight = _flight(wait_reached=True, written_ns=None)
    flight.on_angles((30.0, -20.0, 0, 0, 0, 0, 0))  # already at the target before it is sent
    assert not flight.done and flight.reached is None


def test_reached_without_acks_still_completes() -> None:
    # The arm's acks are known to be unreliable: feedback showing the target is what counts.
    flight = _flight(wait_reached=True)
    flight.on_angles((30.0, -20.0, 0, 0, 0, 0, 0))
    assert flight.done
    reply = flight.reply(101.0)
    assert reply.ok and reply.reached is True and reply.received is False


def test_not_reached_times_out_naming_the_worst_joint() -> None:
    flight = _flight(wait_reached=True)
    flight.on_ack(p.ReceiveAck(5, True))
    flight.on_ack(p.ExecuteAck(5, True))
    angles = (29.0, -5.0, 0, 0, 0, 0, 0)
    flight.on_angles(angles)
    flight.on_time(109.99, angles)
    assert not flight.done
    flight.on_time(110.0, angles)
    assert flight.done
    reply = flight.reply(110.0)
    assert not reply.ok and reply.reached is False
    assert reply.error is not None and reply.error.code == ErrorCode.NOT_REACHED
    assert "not reached within 10.0 s" in reply.error.message
    assert "joint 1 is 15.0 deg away" in reply.error.message


def test_angles_are_ignored_unless_reach_was_asked() -> None:
    flight = _flight()
    flight.on_angles((30.0, -20.0, 0, 0, 0, 0, 0))
    assert flight.reached is None and not flight.done


# ----------------------------------------------------------------------------- tracker


def test_tracker_starts_lost_and_unknown() -> None:
    tracker = ArmTracker(ArmConfig(id="a1"))
    assert tracker.link == "lost"
    assert tracker.angles_deg is None and tracker.powered is None
    assert tracker.feedback_age_s(5.0) is None
    assert tracker.update_link(5.0) is False  # still lost: no change


def test_link_ok_then_stale_then_lost_with_the_default_thresholds() -> None:
    tracker = ArmTracker(ArmConfig(id="a1"))  # stale after 0.35 s, lost after 2 s
    tracker.on_feedback(_feedback(), now=10.0)
    assert tracker.update_link(10.0) is True and tracker.link == "ok"
    assert tracker.update_link(10.35) is False and tracker.link == "ok"
    assert tracker.update_link(10.36) is True and tracker.link == "stale"
    assert tracker.update_link(12.0) is False and tracker.link == "stale"
    assert tracker.update_link(12.01) is True and tracker.link == "lost"
    tracker.on_feedback(_feedback(), now=13.0)
    assert tracker.update_link(13.05) is True and tracker.link == "ok"


def test_link_thresholds_come_from_the_config() -> None:
    tracker = ArmTracker(ArmConfig(id="a1", link_stale_s=1.0, link_lost_s=5.0))
    tracker.on_feedback(_feedback(), now=0.0)
    tracker.update_link(0.9)
    assert tracker.link == "ok"
    tracker.update_link(1.1)
    assert tracker.link == "stale"
    tracker.update_link(4.9)
    assert tracker.link == "stale"
    tracker.update_link(5.1)
    assert tracker.link == "lost"


def test_any_valid_message_refreshes_the_link() -> None:
    tracker = ArmTracker(ArmConfig(id="a1"))
    tracker.on_feedback(_feedback(), now=0.0)
    tracker.on_feedback(p.encode_message(p.ReceiveAck(3, True)), now=1.0)
    tracker.update_link(1.2)
    assert tracker.link == "ok"


def test_malformed_and_unknown_are_counted_and_do_not_refresh_the_link() -> None:
    tracker = ArmTracker(ArmConfig(id="a1"))
    tracker.on_feedback(_feedback(), now=0.0)
    assert tracker.on_feedback("not json", now=1.0) is None
    assert tracker.on_feedback('{"seq":10,"address":2,"funcode":1,"data":{}}', now=1.0) is None
    assert (
        tracker.on_feedback('{"seq":10,"address":2,"funcode":1,"data":{"angle0":NaN}}', 1.0) is None
    )
    assert tracker.malformed == 3
    assert tracker.last_error is not None and tracker.last_error.startswith("malformed feedback")
    assert tracker.on_feedback('{"seq":10,"address":9,"funcode":9,"data":{}}', now=1.0) is None
    assert tracker.unknown_messages == 1
    assert tracker.malformed == 3
    assert "address=9 funcode=9" in (tracker.last_error or "")
    assert tracker.relayed == 1
    assert tracker.last_feedback_s == 0.0
    tracker.update_link(1.0)
    assert tracker.link == "stale"
    assert tracker.angles_deg == HOME


def test_unknown_fields_are_counted_but_the_message_is_used() -> None:
    tracker = ArmTracker(ArmConfig(id="a1"))
    text = (
        '{"seq":10,"address":2,"funcode":3,"x":1,'
        '"data":{"enable_status":0,"power_status":1,"error_status":0,"t":3}}'
    )
    decoded = tracker.on_feedback(text, now=0.0)
    assert decoded is not None and decoded.unknown_fields == ("x", "data.t")
    assert tracker.unknown_fields == 2
    assert (tracker.enabled, tracker.powered, tracker.error_status) == (False, True, 0)


def test_status_motors_and_payloads() -> None:
    tracker = ArmTracker(ArmConfig(id="a1"))
    tracker.on_feedback(_feedback(), now=0.0)
    tracker.on_feedback(p.encode_message(p.D1Status(True, True, 1)), now=0.1)
    motors = (True, True, False, True, True, True, True)
    tracker.on_feedback(p.encode_message(p.MotorStatus(motors)), now=0.2)
    tracker.update_link(0.3)
    status = tracker.status(now=0.3, stamp_ns=123)
    assert status == m.ArmStatus(
        stamp_ns=123,
        link="ok",
        enabled=True,
        powered=True,
        error=False,
        motors_ok=list(motors),
        estopped=False,
        feedback_age_s=0.1,
        error_status=1,
    )
    tracker.on_feedback("garbage", now=0.3)
    diag = tracker.diag(now=0.3, stamp_ns=124)
    assert (diag.relayed, diag.malformed, diag.unknown_messages, diag.link) == (3, 1, 0, "ok")
    assert diag.last_feedback_age_s == 0.1
    assert diag.last_error is not None


def test_feedback_rate_is_measured_over_the_recent_window() -> None:
    tracker = ArmTracker(ArmConfig(id="a1"))
    assert tracker.feedback_rate_hz() == 0.0
    for i in range(40):
        tracker.on_feedback(_feedback(), now=i * 0.1)
    assert tracker.feedback_rate_hz() == pytest.approx(10.0)
    for i in range(20):
        tracker.on_feedback(_feedback(), now=4.0 + i * 0.2)
    assert tracker.feedback_rate_hz() == pytest.approx(5.0)


# ----------------------------------------------------------------------------- ArmSafety


def test_a_stop_also_asked_by_a_heartbeat_is_released_with_the_latched_one() -> None:
    from fleet.devices.safety import ArmSafety

    safety = ArmSafety(lease_s=3.0, watchdog_s=0.5)
    assert safety.latch("s1", "ann", "", 0.0, 0)
    safety.note_also_stopped_by("s2")  # a heartbeat repeats another stop: nothing to write
    assert not safety.latch("s2", "bob", "", 0.1, 1)  # its repeats do not latch again
    released = safety.reset()
    assert released is not None and released.stop_id == "s1"
    assert not safety.latch("s2", "bob", "", 0.2, 2)  # released with s1 by the reset
    assert safety.latch("s3", "bob", "", 0.3, 3)


def test_the_watchdog_counts_the_watch_start_as_a_beat() -> None:
    from fleet.devices.safety import ArmSafety

    safety = ArmSafety(lease_s=3.0, watchdog_s=0.5)
    safety.watch("coordinator/c", now_s=10.0)
    assert not safety.watchdog_expired(None, 10.4)  # not heard yet, but only just watched
    assert safety.watchdog_expired(None, 10.6)
    assert not safety.watchdog_expired(10.5, 10.9)
    assert safety.watchdog_expired(10.5, 11.1)
    assert safety.latch("s", "x", "", 11.1, 0)
    assert not safety.watchdog_expired(None, 20.0)  # a stop ends the watch


def test_unload_and_power_off_stops_wait_for_the_arms_status() -> None:
    from fleet.devices.safety import ArmSafety

    safety = ArmSafety(lease_s=3.0, watchdog_s=0.5)
    assert safety.latch("s", "x", "", 0.0, 0, action="power_off")
    for i in range(3):
        safety.on_angles((0.0,) * 7, i, 0.1 * i)
    assert safety.stop is not None and safety.stop.still_ns is not None
    assert not safety.stop.done and safety.needs_resend(1.0)  # still, but not yet unpowered
    assert not safety.on_status(enabled=True, powered=True, now_ns=5)
    assert safety.on_status(enabled=True, powered=False, now_ns=6)
    assert safety.stop.done and not safety.needs_resend(2.0)


# ----------------------------------------------------------------------------- feedback trust


ARM_HOST = "arm-1 udp/192.168.123.100"


def _text(message: p.ArmMessage) -> str:
    return p.encode_message(message)


def test_the_arms_own_writers_on_its_host_are_trusted_a_second_angle_writer_is_not() -> None:
    """Seed 000's driver publishes rt/arm_Feedback from three services (three participants on
    the arm's card): angles from one, acks from another, status from a third all count."""
    tracker = ArmTracker(ArmConfig(id="a1"))
    angles, acks, status = (SampleWriter(h, ARM_HOST) for h in (7, 8, 9))
    assert tracker.on_feedback(_feedback(HOME), 0.0, angles) is not None
    assert tracker.on_feedback(_text(p.ReceiveAck(4, True)), 0.02, acks) is not None
    assert tracker.on_feedback(_text(p.ExecuteAck(4, True)), 0.03, status) is not None
    status_text = _text(p.D1Status(True, True, 1))
    assert tracker.on_feedback(status_text, 0.05, status) is not None
    assert tracker.foreign == 0 and tracker.enabled is True
    # A second writer of angles, even on the arm's host (a process beside the arm's services).
    forged = (80.0, 30.0, 30.0, 0.0, 0.0, 0.0, 10.0)
    assert tracker.on_feedback(_feedback(forged), 0.06, acks) is None
    # Any writer on another host (a rogue participant elsewhere on the arm's network).
    rogue = SampleWriter(11, "laptop udp/192.168.123.50")
    assert tracker.on_feedback(_text(p.ExecuteAck(5, True)), 0.07, rogue) is None
    assert tracker.on_feedback(status_text, 0.08, rogue) is None
    assert tracker.foreign == 3 and tracker.angles_deg == HOME
    # The angle writer keeps its report while it speaks ...
    assert tracker.on_feedback(_feedback(HOME), 1.5, angles) is not None
    assert tracker.on_feedback(_feedback(HOME), 1.6, acks) is None
    # ... a restarted service (a new writer) takes its report over once the old one was silent
    # for link_lost_s; a replaced arm (another host) once the whole arm was.
    later = 1.5 + tracker.config.link_lost_s + 0.1
    assert tracker.on_feedback(status_text, later - 0.2, status) is not None
    assert tracker.on_feedback(_feedback(HOME), later, acks) is not None
    assert tracker.on_feedback(_feedback(HOME), later + 0.1, rogue) is None
    replaced = later + 0.1 + tracker.config.link_lost_s + 0.1
    assert tracker.on_feedback(_feedback(HOME), replaced, rogue) is not None


def test_writers_of_no_named_host_are_one_group() -> None:
    """A participant that announces no host (another DDS vendor): such writers are one host."""
    tracker = ArmTracker(ArmConfig(id="a1"))
    assert tracker.on_feedback(_feedback(HOME), 0.0, SampleWriter(7, None)) is not None
    assert tracker.on_feedback(_text(p.ExecuteAck(4, True)), 0.1, SampleWriter(8, None))
    forged = (80.0, 30.0, 30.0, 0.0, 0.0, 0.0, 10.0)
    assert tracker.on_feedback(_feedback(forged), 0.2, SampleWriter(9, None)) is None
    assert tracker.on_feedback(_feedback(HOME), 0.3, SampleWriter(9, ARM_HOST)) is None
    assert tracker.foreign == 2


def test_an_impossible_jump_is_never_the_pose_unless_it_persists() -> None:
    tracker = ArmTracker(ArmConfig(id="a1", max_speed_deg_s=360.0))
    tracker.on_feedback(_feedback(HOME), 0.0)
    jumped = (HOME[0] + 80.0, *HOME[1:])
    assert tracker.on_feedback(_feedback(jumped), 0.1) is None  # 800 deg/s
    assert tracker.implausible == 1 and tracker.angles_deg == HOME
    moved = (HOME[0] + 30.0, *HOME[1:])
    assert tracker.on_feedback(_feedback(moved), 0.2) is not None  # 300 deg/s: plausible
    # A real jump (an unloaded arm that fell) is followed after three agreeing reports.
    fallen = (HOME[0] + 30.0, HOME[1] - 85.0, *HOME[2:])
    assert tracker.on_feedback(_feedback(fallen), 0.3) is None
    assert tracker.on_feedback(_feedback(fallen), 0.4) is None
    assert tracker.on_feedback(_feedback(fallen), 0.5) is not None
    assert tracker.angles_deg == fallen


# ----------------------------------------------------------------------------- enable strength


def test_a_pose_that_drifts_after_an_enable_is_warned_once() -> None:
    from fleet.d1arm.sag import SagCheck

    check = SagCheck()
    check.armed(HOME, 0.0, "enable_mode 1")
    assert check.on_angles(HOME, 0.1) is None
    sagged = (HOME[0], HOME[1] - 3.0, *HOME[2:])
    warning = check.on_angles(sagged, 0.5)
    assert (
        warning is not None and "joint 1 drifted 3.0 deg" in warning and "enable_mode 1" in warning
    )
    assert check.on_angles(sagged, 0.6) is None and check.sagged == 1
    check.armed(HOME, 1.0, "enable_mode 80000")
    assert check.on_angles(HOME, 2.1) is None  # held for the whole window
    assert check.on_angles(sagged, 2.2) is None  # past it: a later motion is not a sag
    check.armed(HOME, 3.0, "x")
    check.cancel()  # a motion command was written
    assert check.on_angles(sagged, 3.5) is None
