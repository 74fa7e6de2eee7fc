"""The G1's waist and arms through ``rt/arm_sdk`` (seed 004): joint table, target checks and
the weight ramp. Pure (times are passed in; no DDS).

``rt/arm_sdk`` takes a ``unitree_hg`` ``LowCmd_``: motors 12-28 (waist yaw/roll/pitch, then the
left and the right arm, 7 joints each) and, on motor 29, ``q`` as the weight in 0..1 with which
the robot's own controller blends our targets into its own. The agent streams it every
``PERIOD_S`` (50 Hz). The weight ramps 0 -> 1 over ``engage_s`` when control starts and 1 -> 0
over ``release_s`` (at least 1 s) on a release, a lease that ran out (no new target for
``hold_s``), the watchdog's or an operator's stop, or a state that no longer allows it: one
step per message, never more than ``MAX_WEIGHT_STEP`` (the config check keeps it so). The
commanded pose starts at the measured one (no jump at engage), moves towards the target at
most ``speed_rad_s`` per second on every joint, and holds while releasing.

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
    release_s: float = 1.0
    hold_s: float = 3.0
    """No new target for this long (the lease): released."""
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


Phase = Literal["off", "engaging", "on", "releasing"]


@dataclass
class ArmStream:
    """One G1's arm stream: weight, commanded pose, target. Stepped once per message."""

    limits: ArmLimits
    phase: Phase = "off"
    weight: float = 0.0
    q_cmd: list[float] = field(default_factory=list)
    target: list[float] = field(default_factory=list)
    speed_rad_s: float = 0.5
    last_target_s: float = 0.0
    why_released: str | None = None
    tail: int = 0

    @property
    def active(self) -> bool:
        """Messages are due (streaming, or the weight-0 tail of a release)."""
        return self.phase != "off" or self.tail > 0

    def set_target(
        self, q_rad: list[float], speed_rad_s: float, measured: list[float], now_s: float
    ) -> None:
        """A checked target; from off (or mid-release) the stream (re)engages, the commanded
        pose starting at the measured one when the weight is 0."""
        if self.phase == "off" or self.weight == 0.0:
            self.q_cmd = list(measured)
        if self.phase in ("off", "releasing"):
            self.phase = "engaging"
        self.target, self.speed_rad_s, self.last_target_s = list(q_rad), speed_rad_s, now_s
        self.why_released = None

    def release(self, why: str) -> bool:
        """Ramp the weight down (idempotent); True if this started a release."""
        if self.phase in ("off", "releasing"):
            return False
        self.phase, self.why_released = "releasing", why
        return True

    def step(self, now_s: float) -> tuple[float, list[float]] | None:
        """The next message's (weight, 17 commanded q), or None when nothing is due."""
        if self.phase in ("engaging", "on") and now_s - self.last_target_s > self.limits.hold_s:
            self.release(f"no new target for {self.limits.hold_s:g} s (lease)")
        if self.phase == "off":
            if self.tail <= 0:
                return None
            self.tail -= 1
            return 0.0, self.q_cmd
        if self.phase == "engaging":
            self.weight = min(1.0, self.weight + self.up_step)
            if self.weight >= 1.0:
                self.phase = "on"
        elif self.phase == "releasing":
            self.weight = max(0.0, self.weight - self.down_step)
            if self.weight <= 0.0:
                self.phase, self.tail = "off", TAIL_MESSAGES
            return self.weight, self.q_cmd
        limit = self.speed_rad_s * PERIOD_S
        self.q_cmd = [
            q + max(-limit, min(limit, t - q)) for q, t in zip(self.q_cmd, self.target, strict=True)
        ]
        return self.weight, self.q_cmd

    @property
    def up_step(self) -> float:
        """The weight's step per message while engaging."""
        return min(MAX_WEIGHT_STEP, PERIOD_S / self.limits.engage_s)

    @property
    def down_step(self) -> float:
        """The weight's step per message while releasing."""
        return min(MAX_WEIGHT_STEP, PERIOD_S / self.limits.release_s)
