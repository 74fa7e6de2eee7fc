"""The simulated D1 arm's behaviour: pure state and physics, no transport, injected time.

What it models, and why:
- joint tracking with the two smoothing modes of 1/2: mode 0 (small smoothing, for streaming
  at 10 Hz) follows quickly, mode 1 (large smoothing, for big moves) slowly, both speed-limited;
  the response is ``fleet.contact.dynamics`` (dead time, lag, speed limit, second-order servo),
  per arm in the inventory (``sim_dynamics``) so a test can run an arm whose dynamics differ
  from the detector's assumptions;
- enable/unload per joint and power: an unloaded joint or a powered-off arm does not track;
- the field-reported quirk that a re-enabled joint chases its old cached target (so the agent
  must set the target to the measured pose before re-enabling; the sim makes that testable);
- the field-reported quirk that an invalid joint id is acknowledged and then stops the arm's
  angle feed (so nothing invalid may reach it);
- faults for tests: a joint stalled at an angle (an obstacle), a motor offline, error_status 0,
  dropped feedback, acknowledgments that never come;
- contact (``obstacles.py``): compliant obstacles, gripped objects, servo hunting, an obstacle
  pushing into a held joint, an arm that may flag ``error_status`` while pushing; seeded
  feedback noise (``noise_deg``) and extra feedback jitter (``jitter_s``, used by the node).
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from fleet.contact.dynamics import SIM_DEFAULT, JointResponse, SimDynamics
from fleet.d1 import protocol as p
from fleet.d1.errors import InvalidJoint, MalformedMessage
from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG, JointRanges
from fleet.sim.obstacles import Obstacle, constrain

PHYSICS_STEP_S = 0.01
SAG_BELOW = 8000
"""With ``enable_strength``, a funcode 5 ``mode`` below this (10 % of 80000) holds nothing."""
SAG_JOINT, SAG_DEG_S = 1, 20.0
"""The joint that sags in a limp arm, and how fast."""

SMOOTHING = {mode: (d.lag_s, d.rate_deg_s) for mode, d in SIM_DEFAULT.items()}
"""(time constant s, speed limit deg/s) per smoothing mode of the default simulated arm."""


@dataclass
class Faults:
    """Injected faults; all off by default."""

    stalls: dict[int, float] = field(default_factory=dict)
    motors_offline: set[int] = field(default_factory=set)
    error_status: bool = False
    abnormal_value: int = 0
    """The ``error_status`` reported while abnormal: 0 per the spec's table; a bitfield value
    (the contact plan's reading) per arm from the inventory (``sim_error_status``) or a fault."""
    drop_feedback: bool = False
    mute_acks: bool = False
    # joint -> (angle the hand drags it to, speed deg/s): moves only an unloaded joint
    drags: dict[int, tuple[float, float]] = field(default_factory=dict)
    # joint -> a compliant obstacle (or, on joint 6, the object the gripper closes on)
    obstacles: dict[int, Obstacle] = field(default_factory=dict)
    noise_deg: float = 0.0
    """Standard deviation of Gaussian noise on reported angles (seeded by the model's rng)."""
    jitter_s: float = 0.0
    """Extra feedback period jitter, uniform 0..jitter_s (applied by the node)."""


@dataclass
class SimArmModel:
    """One simulated arm. Call ``advance(now_s)`` before reading or commanding it."""

    angles_deg: list[float] = field(default_factory=lambda: [0.0] * JOINT_COUNT)
    target_deg: list[float] = field(default_factory=lambda: [0.0] * JOINT_COUNT)
    enabled: list[bool] = field(default_factory=lambda: [True] * JOINT_COUNT)
    powered: bool = True
    mode: int = 1
    angle_feed_stopped: bool = False
    faults: Faults = field(default_factory=Faults)
    time_s: float = 0.0
    joint_ranges_deg: JointRanges = JOINT_RANGE_DEG
    """What the arm accepts (its gripper's own range, from the inventory)."""
    rng: random.Random = field(default_factory=lambda: random.Random(0), repr=False)
    dynamics: SimDynamics = field(default_factory=SimDynamics)
    enable_strength: bool = False
    """Funcode 5 ``mode`` read as a 0..80000 strength (``sim_enable = "strength"``): below
    ``SAG_BELOW`` the joints do not hold and the shoulder (joint 1) sags."""
    limp: bool = False
    exec_ack_on_arrival: bool = False
    """The execute ack of a motion (1/1, 1/2, 1/7) comes once the joints reached their targets
    ("executed" as "motion finished"), not at once (``sim_exec_ack``)."""
    arrival_tolerance_deg: float = 0.5
    _pending_exec: list[int] = field(default_factory=list, repr=False)
    # joint -> (stall angle, joint was at or below it when the stall was first met)
    _stall_side: dict[int, tuple[float, bool]] = field(default_factory=dict, repr=False)
    _joints: list[JointResponse] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        self._joints = [JointResponse(a) for a in self.angles_deg]
        for response, target in zip(self._joints, self.target_deg, strict=True):
            response.target_deg, response.mode = target, self.mode

    # ------------------------------------------------------------------ physics

    def advance(self, now_s: float) -> None:
        """Integrate the joints from the last call up to ``now_s`` in fixed steps."""
        if now_s <= self.time_s:
            return
        if self._at_rest():
            self.time_s = now_s  # every step would leave every angle as it is
            return
        steps = min(int((now_s - self.time_s) / PHYSICS_STEP_S) + 1, 1000)
        dt = (now_s - self.time_s) / steps
        for k in range(steps):
            self._step(dt, self.time_s + (k + 1) * dt)
        self.time_s = now_s

    def _at_rest(self) -> bool:
        """True when a physics step cannot change anything: no fault acts on a joint (stall,
        obstacle, drag) and every joint already sits exactly on its target (an untracked joint
        without a drag does not move). An idle arm is this case: the integration, 10 steps of 7
        joints per report, was most of ``fleet sim``'s CPU with hundreds of idle arms."""
        faults = self.faults
        if faults.stalls or faults.obstacles or faults.drags or self._stall_side:
            return False
        return self.angles_deg == self.target_deg and all(r.at_rest() for r in self._joints)

    def _tracking(self, joint: int) -> bool:
        if self.limp:
            return False
        return self.powered and self.enabled[joint] and joint not in self.faults.motors_offline

    def _step(self, dt: float, now_s: float) -> None:
        for j in range(JOINT_COUNT):
            response = self._joints[j]
            response.due(now_s)
            if not response.pending() and response.target_deg != self.target_deg[j]:
                response.target_deg = self.target_deg[j]  # set directly (a test)
            if not self._tracking(j):
                self._dragged(j, dt)
                response.hold(self.angles_deg[j])
                continue
            current = self.angles_deg[j]
            if response.angle_deg != current:
                response.hold(current)  # moved while it did not track (a drag)
            dynamics = self.dynamics.mode(response.mode)
            wanted = response.step(dynamics, dt)
            new = self._stalled(j, current, wanted)
            obstacle = self.faults.obstacles.get(j)
            if obstacle is not None:
                new = constrain(obstacle, current, new, response.target_deg, dt)
                if obstacle.met_s is None and obstacle.pushing_s > 0.0:
                    obstacle.met_s = now_s - dt
            if new != wanted:
                if dynamics.servo_hz > 0.0:
                    response.angle_deg, response.velocity_deg_s = new, 0.0  # blocked
                else:
                    response.hold(new)
            self.angles_deg[j] = new

    def _dragged(self, joint: int, dt: float) -> None:
        """A hand drags an unloaded joint towards its drag angle at the drag speed."""
        drag = self.faults.drags.get(joint)
        if drag is None and self.limp and joint == SAG_JOINT:
            drag = (self.joint_ranges_deg[joint][0], SAG_DEG_S)  # gravity pulls it down
        if drag is None:
            return
        target, speed = drag
        step = max(-speed * dt, min(speed * dt, target - self.angles_deg[joint]))
        self.angles_deg[joint] += step

    def _stalled(self, joint: int, current: float, new: float) -> float:
        """An obstacle at ``stall``: the joint cannot cross it from the side it was on when it
        first met the stall (a joint resting on it then counts as below it). The side is
        remembered: a joint that reached the obstacle from above rests on it, still above."""
        stall = self.faults.stalls.get(joint)
        if stall is None:
            self._stall_side.pop(joint, None)
            return new
        side = self._stall_side.get(joint)
        if side is None or side[0] != stall:
            side = (stall, current <= stall)
            self._stall_side[joint] = side
        return min(new, stall) if side[1] else max(new, stall)

    # ------------------------------------------------------------------ commands

    def apply(self, text: str) -> list[p.ArmMessage]:
        """Handle one command string as the arm's service does; returns the acks to send."""
        try:
            seq, command = p.decode_command(text, self.joint_ranges_deg)
        except InvalidJoint as exc:
            # Field report: the arm acks an invalid joint id, then its angle feed stops.
            self.angle_feed_stopped = True
            return self._acks(exc.seq, received=True, executed=False) if exc.seq is not None else []
        except (p.InvalidCommand, MalformedMessage) as exc:
            return self._acks(exc.seq, received=False, executed=None) if exc.seq is not None else []
        executed = self._execute(command)
        motion = isinstance(command, (p.SetJointAngle, p.SetAllAngles, p.ReturnToZero))
        if executed and motion and self.exec_ack_on_arrival and not self.faults.mute_acks:
            self._pending_exec.append(seq)
            return self._acks(seq, received=True, executed=None)
        return self._acks(seq, received=True, executed=executed)

    def arrived_acks(self) -> list[p.ArmMessage]:
        """The execute acks of motions that have now reached their targets (every motion
        pending: the newest target is the one reached)."""
        if not self._pending_exec:
            return []
        reached = all(
            abs(a - t) <= self.arrival_tolerance_deg
            for a, t in zip(self.angles_deg, self.target_deg, strict=True)
        )
        if not reached:
            return []
        seqs, self._pending_exec = self._pending_exec, []
        return [p.ExecuteAck(seq, True) for seq in seqs]

    def _acks(self, seq: int, received: bool, executed: bool | None) -> list[p.ArmMessage]:
        if self.faults.mute_acks:
            return []
        acks: list[p.ArmMessage] = [p.ReceiveAck(seq, received)]
        if executed is not None:
            acks.append(p.ExecuteAck(seq, executed))
        return acks

    def _execute(self, command: p.Command) -> bool:
        if isinstance(command, p.SetPower):
            self.powered = command.on
            return True
        if isinstance(command, p.SetAllTorque):
            self.enabled = [command.mode > 0] * JOINT_COUNT
            self.limp = self.enable_strength and 0 < command.mode < SAG_BELOW
            return self.powered
        if isinstance(command, p.SetJointTorque):
            self.enabled[command.joint] = command.enable
            return self.powered
        if not self.powered:
            return False
        if isinstance(command, p.SetJointAngle):
            self.target_deg[command.joint] = command.angle_deg
            self._command((command.joint,))
        elif isinstance(command, p.SetAllAngles):
            self.target_deg = list(command.angles_deg)
            self.mode = command.mode
            self._command(range(JOINT_COUNT))
        elif isinstance(command, p.ReturnToZero):
            self.target_deg = [0.0] * JOINT_COUNT
            self.mode = 1
            self._command(range(JOINT_COUNT))
        return True

    def _command(self, joints: range | tuple[int, ...]) -> None:
        """The servos of ``joints`` see their new targets after the mode's dead time."""
        dead_s = self.dynamics.mode(self.mode).dead_s
        for j in joints:
            self._joints[j].command(self.target_deg[j], self.mode, self.time_s, dead_s)
            if dead_s <= 0.0:
                self._joints[j].due(self.time_s)

    # ------------------------------------------------------------------ reports

    def joint_report(self) -> p.JointAngles | None:
        """The 2/1 report, or None while the feed is stopped (a fault or the bad-id quirk)."""
        if self.faults.drop_feedback or self.angle_feed_stopped:
            return None
        noise = self.faults.noise_deg
        if noise > 0.0:
            return p.JointAngles(
                tuple(round(a + self.rng.gauss(0.0, noise), 2) for a in self.angles_deg)
            )
        return p.JointAngles(tuple(round(a, 2) for a in self.angles_deg))

    def status_reports(self) -> list[p.ArmMessage]:
        """The 2/3 and 2/4 reports."""
        if self.faults.drop_feedback:
            return []
        motors = tuple(j not in self.faults.motors_offline for j in range(JOINT_COUNT))
        return [
            p.D1Status(
                enabled=any(self.enabled),
                powered=self.powered,
                error_status=self.faults.abnormal_value
                if self.faults.error_status
                or any(o.raises_error for o in self.faults.obstacles.values())
                else p.ERROR_STATUS_NORMAL,
            ),
            p.MotorStatus(motors),
        ]
