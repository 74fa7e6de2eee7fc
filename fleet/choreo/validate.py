"""Checks of a whole script before the first move: joint limits and speed limits. Pure.

Every keyframe must be inside the D1's joint ranges (``fleet/d1/limits.py``), and every segment,
from each arm's measured start pose through every keyframe and around the loop, must stay under
the script's ``max_speed_deg_s`` at the easing's peak speed.
"""

from __future__ import annotations

from collections.abc import Mapping

from fleet.choreo.script import Move, Pose, Script, ScriptError
from fleet.choreo.timeline import PEAK_SPEED_FACTOR
from fleet.d1.limits import JOINT_RANGE_DEG, JointRanges


def limit_problems(script: Script, ranges: Mapping[str, JointRanges] | None = None) -> list[str]:
    """Every keyframe joint outside its range (``ranges``: each arm's, from the inventory, whose
    gripper may read another way; default the spec's), as ``step[i].arm joint j: ...`` lines."""
    problems = []
    for index, step in enumerate(script.steps):
        if not isinstance(step, Move):
            continue
        for arm, pose in step.poses.items():
            arm_ranges = JOINT_RANGE_DEG if ranges is None else ranges.get(arm, JOINT_RANGE_DEG)
            for joint, (angle, (low, high)) in enumerate(zip(pose, arm_ranges)):
                if not low <= angle <= high:
                    problems.append(
                        f"step[{index}].{arm} joint {joint}: {angle:g} deg is outside "
                        f"{low:g}..{high:g}"
                    )
    return problems


def speed_problems(script: Script, start_poses: Mapping[str, Pose]) -> list[str]:
    """Every segment whose peak joint speed exceeds the script's ``max_speed_deg_s``."""
    problems: list[str] = []
    poses = {a: tuple(start_poses[a]) for a in script.arms}
    passes = 1 if script.loops == 1 else 2  # the second pass checks the loop's wrap-around
    for iteration in range(passes):
        for index, step in enumerate(script.steps):
            if not isinstance(step, Move):
                continue
            factor = PEAK_SPEED_FACTOR[step.easing]
            for arm, goal in step.poses.items():
                for joint, (a, b) in enumerate(zip(poses[arm], goal)):
                    speed = abs(b - a) / step.duration_s * factor
                    if speed > script.max_speed_deg_s + 1e-9:
                        where = "first pass" if iteration == 0 else "after a loop"
                        problems.append(
                            f"step[{index}].{arm} joint {joint}: {speed:.0f} deg/s peak "
                            f"({step.easing}, {where}) exceeds {script.max_speed_deg_s:g} deg/s; "
                            "lengthen duration_s"
                        )
                poses[arm] = goal
    return list(dict.fromkeys(problems))


def check_motion(
    script: Script,
    start_poses: Mapping[str, Pose],
    ranges: Mapping[str, JointRanges] | None = None,
) -> None:
    """Raise ScriptError listing every limit and speed problem (nothing has moved yet)."""
    missing = [a for a in script.arms if a not in start_poses]
    if missing:
        raise ScriptError(f"{script.source}: no measured pose of {', '.join(missing)}")
    problems = limit_problems(script, ranges) + speed_problems(script, start_poses)
    if problems:
        shown = "\n  ".join(problems[:20])
        more = f"\n  ... and {len(problems) - 20} more" if len(problems) > 20 else ""
        raise ScriptError(f"{script.source}: refused before the first move:\n  {shown}{more}")
