"""A G1's arms as choreography parts: their names, limits in degrees and the one target both
make. Pure (no I/O).

A choreography names a G1's arm ``<g1>.left`` or ``<g1>.right`` (``h1.left``): inventory ids
hold no ``.`` (``fleet.wire.keys.check_name``), so the name can be neither an arm nor a group.
In a step, TOML's dotted key ``h1.left = [...]`` reads as the table ``h1 = {left = ...}``; both
spellings (and the quoted ``"h1.left"``) are accepted.

A G1 arm's pose is its seven joints in degrees, as a D1 arm's: shoulder pitch, roll, yaw,
elbow, wrist roll, pitch, yaw (``fleet/g1/arms.py``'s order; no gripper). Its limits are the
G1's own: the joint table of ``fleet/g1/arms.py`` and the inventory's ``arm_max_speed_rad_s``.
rt/arm_sdk takes the waist and both arms in one message with one weight, so a G1 with one arm
in a script is commanded whole: the waist and the arm the script does not name hold the pose
measured at the start.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

from fleet.d1.limits import JointRanges
from fleet.g1 import arms
from fleet.g1.config import G1Config
from fleet.inventory import Inventory

SIDES: dict[str, tuple[int, ...]] = {"left": arms.LEFT_ARM, "right": arms.RIGHT_ARM}
"""Each side's offsets into the 17 rt/arm_sdk joints (motors 12-28)."""
WAIST = tuple(range(0, 3))
SEPARATOR = "."
Pose = tuple[float, ...]


def arm_name(g1: str, side: str) -> str:
    """``h1.left``: how a choreography names one arm of G1 ``g1``."""
    return f"{g1}{SEPARATOR}{side}"


def split(name: str) -> tuple[str, str] | None:
    """(g1, side) of a G1 arm name, None for anything else (a D1 arm, a group)."""
    g1, dot, side = name.partition(SEPARATOR)
    return (g1, side) if dot and side in SIDES else None


def is_g1_arm(name: str) -> bool:
    """``name`` is a G1 arm (``h1.left``), not a D1 arm."""
    return split(name) is not None


def g1_ids(inventory: Inventory) -> list[str]:
    """The inventory's G1s (the devices whose arms a choreography may name)."""
    return [d.id for d in inventory.devices.values() if isinstance(d, G1Config)]


def devices_of(names: Iterable[str]) -> dict[str, list[str]]:
    """G1 -> its sides among ``names``, in order (D1 arms left out)."""
    found: dict[str, list[str]] = {}
    for name in names:
        parts = split(name)
        if parts is not None:
            found.setdefault(parts[0], []).append(parts[1])
    return found


def joint_ranges_deg(side: str, limits: arms.ArmLimits | None = None) -> JointRanges:
    """(min, max) in degrees of one side's seven joints (``limits``: the G1's; default the
    29-dof description's)."""
    limits = limits or arms.ArmLimits()
    return tuple(
        (math.degrees(limits.lower[i]), math.degrees(limits.upper[i])) for i in SIDES[side]
    )


def max_speed_deg_s(config: G1Config) -> float:
    """The fastest a script may ask a joint of this G1 to move: its ``arm_max_speed_rad_s``
    (the agent refuses a faster stream)."""
    return math.degrees(config.arm_max_speed_rad_s)


def side_pose_deg(q_rad: Sequence[float], side: str) -> Pose:
    """One side's seven joints, in degrees, from rt/lowstate's 29 positions (rad)."""
    return tuple(math.degrees(q_rad[arms.FIRST + i]) for i in SIDES[side])


def waist_and_arms_rad(q_rad: Sequence[float]) -> list[float]:
    """The 17 rt/arm_sdk joints (motors 12-28) of rt/lowstate's 29 positions."""
    return list(q_rad[arms.FIRST : arms.FIRST + arms.COUNT])


def target_rad(held_rad: Sequence[float], sides_deg: Mapping[str, Pose]) -> list[float]:
    """One rt/arm_sdk target (17 joints, rad): ``held_rad`` (the pose measured at the start)
    with each side of ``sides_deg`` (degrees) in place."""
    q = list(held_rad)
    for side, pose in sides_deg.items():
        for offset, angle in zip(SIDES[side], pose, strict=True):
            q[offset] = math.radians(angle)
    return q
