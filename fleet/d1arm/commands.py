"""Key-space commands -> checked D1 commands, and the bookkeeping of one command in flight.

Pure: the agent calls ``plan`` with the arm's tracked state, writes what it returns, and feeds
acks and feedback to ``InFlight`` until it is finished. Nothing invalid leaves ``plan``: the
real arm acknowledges an invalid joint id and then stops its angle feed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fleet.d1 import protocol as p
from fleet.d1.errors import InvalidCommand
from fleet.d1.limits import JOINT_COUNT
from fleet.d1arm.holds import allowed_while_latched, fresh_pose
from fleet.d1arm.tracker import ArmTracker
from fleet.devices.driver import Refusal
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, ErrorInfo


@dataclass(frozen=True)
class Plan:
    """The D1 commands to send, in order, and the joint targets that mean "reached".

    ``holds``: indices of commands that hold the measured pose; the writer recomputes them from
    the pose fresh at the moment of writing (a pose taken earlier may be stale by then)."""

    commands: tuple[p.Command, ...]
    targets_deg: dict[int, float]
    holds: tuple[int, ...] = ()


def _measured(tracker: ArmTracker, now: float, why: str) -> tuple[float, ...]:
    """The measured pose, only while it is fresh (``holds.fresh_pose``)."""
    arm = tracker.config.id
    if tracker.angles_deg is None:
        raise Refusal(ErrorCode.REJECTED, f"arm {arm!r} sent no angles yet; {why}")
    here = fresh_pose(tracker, now)
    if here is None:
        raise Refusal(
            ErrorCode.REJECTED, f"arm {arm!r} has no fresh feedback (link {tracker.link}); {why}"
        )
    return here


def _check_latch(command: m.ArmCommand, tracker: ArmTracker) -> None:
    """Refuse what a latched stop does not allow (``holds.allowed_while_latched``)."""
    arm, action = tracker.config.id, tracker.config.stop_action
    if not tracker.estopped or allowed_while_latched(command, action):
        return
    if isinstance(command, (m.Torque, m.Power)) and not command.on:
        what = "torque off" if isinstance(command, m.Torque) else "power off"
        raise Refusal(
            ErrorCode.REJECTED,
            f"arm {arm!r} is held by a protective stop: {what} would let it fall; "
            f"`fleet reset {arm}` first (the arm then holds its pose) and send it as its owner",
        )
    if isinstance(command, m.MOTION_OPS):
        raise Refusal(
            ErrorCode.REJECTED,
            f"arm {arm!r} is stopped (protective stop latched); `fleet reset {arm}` releases it",
        )
    raise Refusal(ErrorCode.REJECTED, f"arm {arm!r} is stopped; reset it first")


def _check_can_move(tracker: ArmTracker) -> None:
    arm = tracker.config.id
    if tracker.link != "ok":
        raise Refusal(
            ErrorCode.REJECTED,
            f"arm {arm!r} has no fresh feedback (link {tracker.link}); is the arm on and wired?",
        )
    if tracker.powered is False:
        raise Refusal(
            ErrorCode.REJECTED, f"arm {arm!r} is powered off; send `power on` before moving it"
        )


def plan(command: m.ArmCommand, tracker: ArmTracker, now: float) -> Plan:
    """Check ``command`` against the limits and the arm's state at ``now`` (monotonic s);
    raises Refusal."""
    try:
        result = _plan(command, tracker, now)
        for d1_command in result.commands:
            p.validate_command(d1_command, tracker.config.joint_ranges_deg)
    except InvalidCommand as exc:
        raise Refusal(ErrorCode.PARAMETER, str(exc)) from None
    return result


def _plan(command: m.ArmCommand, tracker: ArmTracker, now: float) -> Plan:
    if isinstance(command, m.MoveJoint):
        p.check_angle(command.joint, command.angle_deg, tracker.config.joint_ranges_deg)
        _check_latch(command, tracker)
        _check_can_move(tracker)
        return Plan(
            (p.SetJointAngle(command.joint, command.angle_deg),), {command.joint: command.angle_deg}
        )
    if isinstance(command, m.MoveJoints):
        angles = tuple(command.angles_deg)
        p.validate_command(p.SetAllAngles(angles, command.mode), tracker.config.joint_ranges_deg)
        _check_latch(command, tracker)
        _check_can_move(tracker)
        return Plan((p.SetAllAngles(angles, command.mode),), dict(enumerate(angles)))
    if isinstance(command, m.Zero):
        _check_latch(command, tracker)
        _check_can_move(tracker)
        return Plan((p.ReturnToZero(),), dict.fromkeys(range(JOINT_COUNT), 0.0))
    if isinstance(command, m.Hold):
        # Hold is allowed while stopped: it is what a stop does. It is written at once, with
        # the pose of that moment: a hold scheduled for later would drag the arm back to now.
        if command.start_at_ns is not None:
            raise Refusal(
                ErrorCode.PARAMETER,
                "hold takes the pose of the moment it is written: start_at_ns is refused",
            )
        here = _measured(tracker, now, "cannot hold an unknown pose")
        return Plan((p.SetAllAngles(here, 0),), dict(enumerate(here)), holds=(0,))
    _check_latch(command, tracker)
    if isinstance(command, m.Torque):
        return _plan_torque(command, tracker, now)
    if isinstance(command, m.Power):
        return Plan((p.SetPower(command.on),), {})
    raise Refusal(ErrorCode.NOT_IMPLEMENTED, f"unknown command {type(command).__name__}")


def _plan_torque(command: m.Torque, tracker: ArmTracker, now: float) -> Plan:
    if command.joint is not None:
        p.check_joint(command.joint)
    if command.strength is not None and command.joint is not None:
        raise InvalidCommand("strength applies to all joints only (joint must be null)")
    if not command.on:
        off: p.Command = (
            p.SetAllTorque(0) if command.joint is None else p.SetJointTorque(command.joint, False)
        )
        return Plan((off,), {})
    # Field report: a re-enabled D1 chases its old cached target. Make the measured pose the
    # target first, so enabling never moves the arm.
    here = _measured(tracker, now, "cannot set the target to the measured pose before enabling")
    on: p.Command = (
        p.SetAllTorque(
            command.strength if command.strength is not None else tracker.config.enable_mode
        )
        if command.joint is None
        else p.SetJointTorque(command.joint, True)
    )
    return Plan((p.SetAllAngles(here, 0), on), {}, holds=(0,))


@dataclass
class InFlight:
    """One key-space command waiting for its acks (and, if asked, for the target)."""

    arm: str
    seqs: tuple[int, ...]
    started_s: float
    recv_deadline_s: float
    exec_deadline_s: float
    reach_deadline_s: float | None
    targets_deg: dict[int, float]
    tolerance_deg: float
    received: set[int] = field(default_factory=set)
    executed: set[int] = field(default_factory=set)
    reached: bool | None = None
    error: ErrorInfo | None = None
    written_ns: int | None = None

    def on_ack(self, ack: p.ReceiveAck | p.ExecuteAck) -> None:
        """Record an acknowledgment for one of our seqs."""
        if isinstance(ack, p.ReceiveAck):
            if not ack.ok:
                self.fail(ErrorCode.ARM_REFUSED, f"the arm refused seq {ack.seq} (recv_status 0)")
            self.received.add(ack.seq)
        else:
            if not ack.ok:
                self.fail(
                    ErrorCode.ARM_FAILED,
                    f"the arm failed to execute seq {ack.seq} (exec_status 0)",
                )
            self.executed.add(ack.seq)

    def on_angles(self, angles_deg: tuple[float, ...]) -> None:
        """Check the measured angles against the targets (only when the caller asked, and only
        once the command was written: a delayed start is not "reached" before it is sent)."""
        if self.reach_deadline_s is None or self.reached or self.written_ns is None:
            return
        if all(abs(angles_deg[j] - t) <= self.tolerance_deg for j, t in self.targets_deg.items()):
            self.reached = True

    def on_time(self, now: float, angles_deg: tuple[float, ...] | None) -> None:
        """Apply the deadlines."""
        if self.error is not None or self.done:
            return
        if self.reach_deadline_s is not None:
            if now >= self.reach_deadline_s and not self.reached:
                self.reached = False
                worst = _worst_joint(self.targets_deg, angles_deg)
                waited = self.reach_deadline_s - self.started_s
                self.fail(ErrorCode.NOT_REACHED, f"target not reached within {waited:.1f} s{worst}")
            return
        if now >= self.recv_deadline_s and len(self.received) < len(self.seqs):
            self.fail(
                ErrorCode.TIMEOUT,
                f"no receive ack from the arm within {self.recv_deadline_s - self.started_s:.2f} s",
            )
        elif now >= self.exec_deadline_s and len(self.executed) < len(self.seqs):
            self.fail(
                ErrorCode.TIMEOUT,
                f"no execute ack from the arm within {self.exec_deadline_s - self.started_s:.2f} s",
            )

    def fail(self, code: ErrorCode, message: str) -> None:
        if self.error is None:
            self.error = ErrorInfo(int(code), f"arm {self.arm!r}: {message}"[:1000])

    @property
    def done(self) -> bool:
        """Finished: failed, or every condition the caller asked for is met."""
        if self.error is not None:
            return True
        if self.reach_deadline_s is not None:
            return bool(self.reached)
        return len(self.received) == len(self.seqs) and len(self.executed) == len(self.seqs)

    def reply(self, now: float) -> m.CommandReply:
        """The key-space reply."""
        n = len(self.seqs)
        return m.CommandReply(
            ok=self.error is None,
            arm=self.arm,
            seq=self.seqs[-1],
            received=len(self.received) == n,
            executed=True
            if len(self.executed) == n
            else (False if self.executed or self.error else None),
            reached=self.reached,
            latency_ms=round((now - self.started_s) * 1000.0, 3),
            error=self.error,
            written_ns=self.written_ns,
        )


def _worst_joint(targets: dict[int, float], angles: tuple[float, ...] | None) -> str:
    if angles is None or not targets:
        return ""
    joint = max(targets, key=lambda j: abs(angles[j] - targets[j]))
    return f" (joint {joint} is {abs(angles[joint] - targets[joint]):.1f} deg away)"
