"""Checks of a whole script before the first move: joint limits and speed limits. Pure.

Every keyframe must be inside its arm's joint ranges (a D1's: ``fleet/d1/limits.py``; a G1
arm's: its own, ``fleet/choreo/g1_arms.py``), and every segment, from each arm's measured start
pose through every keyframe and around the loop, must stay under the script's
``max_speed_deg_s`` (and, for a G1 arm, under its G1's ``arm_max_speed_rad_s``) at the easing's
peak speed.
"""

from __future__ import annotations

from collections.abc import Mapping

from fleet.choreo import g1_arms
from fleet.choreo.script import Move, Pose, Script, ScriptError
from fleet.choreo.timeline import PEAK_SPEED_FACTOR
from fleet.d1.limits import JOINT_RANGE_DEG, JointRanges


def default_ranges(arm: str) -> JointRanges:
    """An arm's ranges when the inventory gives none: a D1's by the spec, a G1 arm's by the
    G1's joint table."""
    parts = g1_arms.split(arm)
    return JOINT_RANGE_DEG if parts is None else g1_arms.joint_ranges_deg(parts[1])


def limit_problems(script: Script, ranges: Mapping[str, JointRanges] | None = None) -> list[str]:
    """Every keyframe joint outside its range (``ranges``: each arm's, from the inventory, whose
    gripper may read another way, and each G1 arm's from its G1; default ``default_ranges``),
    as ``step[i].arm joint j: ...`` lines."""
    problems = []
    ranges = ranges or {}
    for index, step in enumerate(script.steps):
        if not isinstance(step, Move):
            continue
        for arm, pose in step.poses.items():
            arm_ranges = ranges.get(arm) or default_ranges(arm)
            for joint, (angle, (low, high)) in enumerate(zip(pose, arm_ranges)):
                if not low <= angle <= high:
                    problems.append(
                        f"step[{index}].{arm} joint {joint}: {angle:g} deg is outside "
                        f"{low:g}..{high:g}"
                    )
    return problems


def speed_problems(
    script: Script, start_poses: Mapping[str, Pose], caps: Mapping[str, float] | None = None
) -> list[str]:
    """Every segment whose peak joint speed exceeds the script's ``max_speed_deg_s`` or the
    arm's own cap (``caps``: deg/s per arm, a G1 arm's from its G1)."""
    problems: list[str] = []
    caps = caps or {}
    poses = {a: tuple(start_poses[a]) for a in script.arms}
    passes = 1 if script.loops == 1 else 2  # the second pass checks the loop's wrap-around
    for iteration in range(passes):
        for index, step in enumerate(script.steps):
            if not isinstance(step, Move):
                continue
            factor = PEAK_SPEED_FACTOR[step.easing]
            for arm, goal in step.poses.items():
                cap = min(script.max_speed_deg_s, caps.get(arm, script.max_speed_deg_s))
                whose = "" if cap == script.max_speed_deg_s else f" ({arm}'s own limit)"
                for joint, (a, b) in enumerate(zip(poses[arm], goal)):
                    speed = abs(b - a) / step.duration_s * factor
                    if speed > cap + 1e-9:
                        where = "first pass" if iteration == 0 else "after a loop"
                        problems.append(
                            f"step[{index}].{arm} joint {joint}: {speed:.0f} deg/s peak "
                            f"({step.easing}, {where}) exceeds {cap:g} deg/s{whose}; "
                            "lengthen duration_s"
                        )
                poses[arm] = goal
    return list(dict.fromkeys(problems))


def check_motion(
    script: Script,
    start_poses: Mapping[str, Pose],
    ranges: Mapping[str, JointRanges] | None = None,
    caps: Mapping[str, float] | None = None,
) -> None:
    """Raise ScriptError listing every limit and speed problem (nothing has moved yet)."""
    missing = [a for a in script.arms if a not in start_poses]
    if missing:
        raise ScriptError(f"{script.source}: no measured pose of {', '.join(missing)}")
    problems = limit_problems(script, ranges) + speed_problems(script, start_poses, caps)
    if problems:
        shown = "\n  ".join(problems[:20])
        more = f"\n  ... and {len(problems) - 20} more" if len(problems) > 20 else ""
        raise ScriptError(f"{script.source}: refused before the first move:\n  {shown}{more}")
