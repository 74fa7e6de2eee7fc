"""The G1's waist and arms through ``rt/arm_sdk`` (seed 004): joint table, target checks and
the weight. Pure (times are passed in; no DDS).

``rt/arm_sdk`` takes a ``unitree_hg`` ``LowCmd_``: motors 12-28 (waist yaw/roll/pitch, then the
left and the right arm, 7 joints each) and, on motor 29, ``q`` as the weight in 0..1 with which
the robot's own controller blends our targets into its own. The agent streams it every
``PERIOD_S`` (50 Hz). The commanded pose moves towards the target at most ``speed_rad_s`` per
second on every joint.

The weight the robot holds is not observable: seed 004 names motor 29 of ``LowCmd_`` only, and
Unitree's ``g1_arm7_sdk_dds_example`` never reads it back from ``rt/lowstate``; the robot keeps
the last stream's weight when its writer goes away (a restarted agent found it near 1). So the
stream starts as Unitree's example does, at weight 1 on the measured pose: whatever weight the
robot holds, its blend of the measured pose is the measured pose, and nothing moves. Only when
the weight is known to be 0 (this stream ended at 0, or the last message another writer was seen
sending on ``rt/arm_sdk`` had 0) does it ramp 0 -> 1 over ``engage_s`` instead (the robot's own
controller keeps the arms while it blends in).

A stop, the watchdog and a lapsed lease (no new target for ``hold_s``) *hold* by default: the
weight is kept and the commanded pose frozen, streamed until an explicit release (``on_stop =
"release"`` ramps down instead). A release ramps the weight to 0 over ``release_s`` (at least
Unitree's example's 3 s), the commanded pose held, then ``TAIL_MESSAGES`` at 0. An FSM that does
not take ``rt/arm_sdk`` ends the stream at once (the robot ignores it; what weight it holds
afterwards is unknown again).

Joint limits: Unitree's G1 29-dof description (``g1_29dof`` URDF, as mujoco-menagerie ships it).
kp/kd: Unitree's ``g1_arm7_sdk_dds_example`` (60, 1.5), per joint from the inventory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

CMD_TOPIC = "rt/arm_sdk"
LOWSTATE_TOPIC = "rt/lowstate"
MOTORS = 29
"""rt/lowstate's motors in use (of its 35): legs 0-11, waist 12-14, arms 15-28."""
FIRST, COUNT, WEIGHT_INDEX = 12, 17, 29
PERIOD_S = 0.02
MAX_WEIGHT_STEP = 0.05
"""The weight changes at most this much from one message to the next (20 ms)."""
TAIL_MESSAGES = 10
"""Messages at weight 0 after a release (so a lost one cannot leave the last weight in force)."""
DEFAULT_KP, DEFAULT_KD = 60.0, 1.5
MIN_RELEASE_S = 3.0
"""Unitree's example hands the arms back with the weight 1 -> 0 over 3 s: never faster."""
MAX_RELEASE_S = 5.0
"""The agent releases the arms before it exits, within the 8 s every process has from its
SIGTERM (``fleet.runtime.SHUTDOWN_BOUND_S``) with its sessions' closes after it."""

JOINTS: tuple[tuple[str, float, float], ...] = (
    ("waist_yaw", -2.618, 2.618),
    ("waist_roll", -0.52, 0.52),
    ("waist_pitch", -0.52, 0.52),
    ("left_shoulder_pitch", -3.0892, 2.6704),
    ("left_shoulder_roll", -1.5882, 2.2515),
    ("left_shoulder_yaw", -2.618, 2.618),
    ("left_elbow", -1.0472, 2.0944),
    ("left_wrist_roll", -1.97222, 1.97222),
    ("left_wrist_pitch", -1.61443, 1.61443),
    ("left_wrist_yaw", -1.61443, 1.61443),
    ("right_shoulder_pitch", -3.0892, 2.6704),
    ("right_shoulder_roll", -2.2515, 1.5882),
    ("right_shoulder_yaw", -2.618, 2.618),
    ("right_elbow", -1.0472, 2.0944),
    ("right_wrist_roll", -1.97222, 1.97222),
    ("right_wrist_pitch", -1.61443, 1.61443),
    ("right_wrist_yaw", -1.61443, 1.61443),
)
"""Motors 12..28: name, lower and upper limit (rad)."""
LEFT_ARM = tuple(range(3, 10))
RIGHT_ARM = tuple(range(10, 17))
"""Offsets (into the 17) of each arm's 7 joints."""


@dataclass(frozen=True)
class ArmLimits:
    """The inventory's arm settings of one G1."""

    engage_s: float = 1.0
    release_s: float = MIN_RELEASE_S
    hold_s: float = 3.0
    """No new target for this long (the lease): held (or released, by ``on_stop``)."""
    on_stop: Literal["hold", "release"] = "hold"
    """What a stop, the watchdog and a lapsed lease do to the stream."""
    speed_rad_s: float = 0.5
    """The commanded pose's default top speed towards a target."""
    max_speed_rad_s: float = 1.5
    max_jump_rad: float = 0.6
    """A target this far from the measured pose (any joint) is refused."""
    kp: tuple[float, ...] = (DEFAULT_KP,) * COUNT
    kd: tuple[float, ...] = (DEFAULT_KD,) * COUNT
    lower: tuple[float, ...] = tuple(j[1] for j in JOINTS)
    upper: tuple[float, ...] = tuple(j[2] for j in JOINTS)


def target_problem(
    q_rad: list[float], speed_rad_s: float, measured: list[float] | None, limits: ArmLimits
) -> str | None:
    """Why a target is refused (None: fine): its length, a non-finite value, a joint outside
    its limits, a speed above the limit, a joint too far from the measured pose."""
    if len(q_rad) != COUNT:
        return f"q_rad has {len(q_rad)} values; the waist and arms are {COUNT} (motors 12-28)"
    if not all(math.isfinite(q) for q in q_rad) or not math.isfinite(speed_rad_s):
        return "every value must be a finite number"
    for i, q in enumerate(q_rad):
        if not limits.lower[i] <= q <= limits.upper[i]:
            name, lo, hi = JOINTS[i][0], limits.lower[i], limits.upper[i]
            return f"{name} (motor {FIRST + i}) {q:g} rad is outside {lo:g}..{hi:g}"
    if not 0 < speed_rad_s <= limits.max_speed_rad_s:
        return f"speed_rad_s {speed_rad_s:g} is outside 0..{limits.max_speed_rad_s:g} (too fast)"
    if measured is None:
        return "no fresh rt/lowstate: the measured pose is unknown"
    for i, (q, at) in enumerate(zip(q_rad, measured, strict=True)):
        if abs(q - at) > limits.max_jump_rad:
            return (
                f"{JOINTS[i][0]} (motor {FIRST + i}) target {q:g} rad is {abs(q - at):.2f} rad "
                f"from the measured {at:g}: more than {limits.max_jump_rad:g} rad; move there "
                "in steps"
            )
    return None


Phase = Literal["off", "engaging", "on", "holding", "releasing"]


@dataclass
class ArmStream:
    """One G1's arm stream: weight, commanded pose, target. Stepped once per message."""

    limits: ArmLimits
    phase: Phase = "off"
    weight: float | None = None
    """The weight the robot holds as far as we know (None: unknown)."""
    q_cmd: list[float] = field(default_factory=list)
    target: list[float] = field(default_factory=list)
    speed_rad_s: float = 0.5
    last_target_s: float = 0.0
    why_held: str | None = None
    why_released: str | None = None
    tail: int = 0

    @property
    def active(self) -> bool:
        """Messages are due (streaming, or the weight-0 tail of a release)."""
        return self.phase != "off" or self.tail > 0

    def set_target(
        self, q_rad: list[float], speed_rad_s: float, measured: list[float], now_s: float
    ) -> None:
        """A checked target. From off the stream starts on the measured pose: ramping from a
        weight known to be 0, else at weight 1 (see the module docstring); held or releasing,
        it goes on from the commanded pose."""
        if self.phase == "off":
            self.q_cmd, self.tail = list(measured), 0
            if self.weight != 0.0:
                self.weight = 1.0
        self.phase = "on" if self.weight == 1.0 else "engaging"
        self.target, self.speed_rad_s, self.last_target_s = list(q_rad), speed_rad_s, now_s
        self.why_held = self.why_released = None

    def hold(self, why: str) -> bool:
        """Keep the weight and freeze the commanded pose (idempotent); True if this started a
        hold. A release under way goes on."""
        if self.phase not in ("engaging", "on"):
            return False
        self.phase, self.why_held = "holding", why
        return True

    def interrupt(self, why: str) -> bool:
        """A stop, the watchdog or the lease: hold or release, as ``limits.on_stop`` says."""
        return self.hold(why) if self.limits.on_stop == "hold" else self.release(why)

    def release(self, why: str, measured: list[float] | None = None) -> bool:
        """Ramp the weight down (idempotent); True if this started a release. From off, with
        the weight not known to be 0 and ``measured`` given, it starts at weight 1 on the
        measured pose (nothing moves) and ramps from there: a restarted agent can hand back
        the arms a previous one left held."""
        if self.phase == "releasing":
            return False
        if self.phase == "off":
            if self.weight == 0.0 or measured is None:
                return False
            self.q_cmd, self.weight, self.tail = list(measured), 1.0, 0
        self.phase, self.why_released, self.why_held = "releasing", why, None
        return True

    def forget(self, why: str) -> bool:
        """The robot does not take rt/arm_sdk now: stop streaming; the weight it will hold is
        unknown. True if a stream ended."""
        was = self.active
        self.phase, self.tail, self.weight = "off", 0, None
        if was:
            self.why_released, self.why_held = why, None
        return was

    def seen(self, weight: float) -> None:
        """The newest message another writer sent on rt/arm_sdk: while this stream is off,
        the robot holds that weight."""
        if self.phase == "off" and self.tail == 0:
            self.weight = weight if 0.0 <= weight <= 1.0 else None

    def step(self, now_s: float) -> tuple[float, list[float]] | None:
        """The next message's (weight, 17 commanded q), or None when nothing is due."""
        if self.phase in ("engaging", "on") and now_s - self.last_target_s > self.limits.hold_s:
            self.interrupt(f"no new target for {self.limits.hold_s:g} s (lease)")
        if self.phase == "off":
            if self.tail <= 0:
                return None
            self.tail -= 1
            return 0.0, self.q_cmd
        weight = self.weight if self.weight is not None else 1.0
        if self.phase == "holding":
            return weight, self.q_cmd
        if self.phase == "releasing":
            self.weight = weight = max(0.0, weight - self.down_step)
            if weight <= 0.0:
                self.phase, self.tail = "off", TAIL_MESSAGES
            return weight, self.q_cmd
        if self.phase == "engaging":
            self.weight = weight = min(1.0, weight + self.up_step)
            if weight >= 1.0:
                self.phase = "on"
        limit = self.speed_rad_s * PERIOD_S
        self.q_cmd = [
            q + max(-limit, min(limit, t - q)) for q, t in zip(self.q_cmd, self.target, strict=True)
        ]
        return weight, self.q_cmd

    @property
    def up_step(self) -> float:
        """The weight's step per message while engaging."""
        return min(MAX_WEIGHT_STEP, PERIOD_S / self.limits.engage_s)

    @property
    def down_step(self) -> float:
        """The weight's step per message while releasing."""
        return min(MAX_WEIGHT_STEP, PERIOD_S / self.limits.release_s)
