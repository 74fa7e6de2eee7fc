"""What the agent writes to keep an arm where it is, and what a latched stop still allows. Pure.

One hold recipe for every caller (the ``hold`` op, a stop, a reset, the watchdog, a failed
thread, shutdown), with one freshness rule: the measured pose is a target only while its last
angle report is younger than the arm's ``link_stale_s``. A stale pose as a target would move
the arm back to where it was (an arm still coasting, or one that sagged while its feed froze).
With no fresh pose, a hold writes nothing: the latch still refuses every motion, and the stop's
repeat writes the hold as soon as fresh feedback returns.
"""

from __future__ import annotations

from fleet.d1 import protocol as p
from fleet.d1.limits import JOINT_RANGE_DEG, JointRanges
from fleet.d1arm.tracker import ArmTracker
from fleet.wire import messages as m

NO_FRESH_POSE = (
    "no fresh pose (no angle report within link_stale_s): nothing written yet; the hold is "
    "written as soon as feedback returns, and every motion is refused meanwhile"
)


def clamp_to_limits(
    angles: tuple[float, ...], ranges: JointRanges = JOINT_RANGE_DEG
) -> tuple[float, ...]:
    """Measured angles can sit a hair outside the documented range; a hold must not be refused
    (``ranges``: the arm's, ``ArmConfig.joint_ranges_deg``)."""
    return tuple(min(max(a, lo), hi) for a, (lo, hi) in zip(angles, ranges, strict=False))


def fresh_pose(tracker: ArmTracker, now_s: float) -> tuple[float, ...] | None:
    """The measured angles (clamped to the limits) if reported within ``link_stale_s``."""
    angles, reported_s = tracker.angles_deg, tracker.angles_s
    if angles is None or reported_s is None:
        return None
    if now_s - reported_s > tracker.config.link_stale_s:
        return None
    return clamp_to_limits(angles, tracker.config.joint_ranges_deg)


def hold_command(tracker: ArmTracker, now_s: float) -> p.SetAllAngles | None:
    """Make the fresh measured pose the target (mode 0: no large smoothing); None without one."""
    here = fresh_pose(tracker, now_s)
    return None if here is None else p.SetAllAngles(here, 0)


def stop_command(action: str, tracker: ArmTracker, now_s: float) -> p.Command | None:
    """The D1 command of a stop ``action``; None for ``hold`` without a fresh pose."""
    if action == "unload":
        return p.SetAllTorque(0)
    if action == "power_off":
        return p.SetPower(False)
    return hold_command(tracker, now_s)


def allowed_while_latched(command: m.ArmCommand, stop_action: str) -> bool:
    """What a latched stop still lets through: a hold (it is what a stop does), a lease
    release, and unloading or powering off an arm whose stop does not hold it up (after a
    ``hold`` stop, torque off or power off would let the arm fall)."""
    if isinstance(command, (m.Hold, m.Release)):
        return True
    if isinstance(command, (m.Torque, m.Power)) and not command.on:
        return stop_action != "hold"
    return False
