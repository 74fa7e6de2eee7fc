"""Joint facts of the D1-550 that the codec, the agent, the simulator and the viewer share.

The wire carries seven values, ``angle0`` .. ``angle6``, all in degrees. ``angle0``..``angle5``
are the six arm joints with the ranges of the service interface's "Range of Motion" table.

``angle6`` is the gripper. The service interface names it an angle like the others and gives no
unit or range for it; the only documented figure is the claw stroke of 0-65 mm. By default we
treat ``angle6`` as degrees of the gripper servo, 0 = closed, and accept 0..65: the stroke is
the only bound the spec gives, and a conservative envelope is safer than none. Whether a real
D1 reads that way is unknown: each arm's inventory says where its gripper is closed and where
open (``gripper_closed_deg``, ``gripper_open_deg``; measure both readings on the arm). Those two
give the gripper's range (``joint_ranges``: the codec's limits for that arm) and its direction
(``gripper_opening``: the viewer maps it onto the URDF's 0..0.033 m finger travel; the grip
checks ask which way is closing).
"""

from __future__ import annotations

JOINT_COUNT = 7
"""Six arm joints plus the gripper (wire ids 0..6)."""

GRIPPER_JOINT = 6

ARM_JOINT_LIMIT_DEG: tuple[float, ...] = (135.0, 90.0, 90.0, 135.0, 90.0, 135.0)
"""Symmetric limits (+/-) of joints 0..5 from the spec's range-of-motion table."""

GRIPPER_CLOSED_DEG = 0.0
GRIPPER_OPEN_DEG = 65.0
GRIPPER_RANGE_DEG: tuple[float, float] = (GRIPPER_CLOSED_DEG, GRIPPER_OPEN_DEG)
"""The default gripper reading: servo degrees, 0 closed .. 65 open."""

JOINT_RANGE_DEG: tuple[tuple[float, float], ...] = (
    *((-lim, lim) for lim in ARM_JOINT_LIMIT_DEG),
    GRIPPER_RANGE_DEG,
)
"""(min, max) per wire joint id, degrees."""

TORQUE_MODE_MAX = 80000
"""All-joint enable (1/5) ``mode``: 0 fully unloaded .. 80000 fully locked; 1 is "enable"."""

CONTROL_RATE_HZ = 10.0
"""The arm's control cycle and feedback rate."""


JointRanges = tuple[tuple[float, float], ...]


def joint_ranges(closed_deg: float, open_deg: float) -> JointRanges:
    """(min, max) per wire joint id for an arm whose gripper reads ``closed_deg`` closed and
    ``open_deg`` open (either way round)."""
    return (
        *JOINT_RANGE_DEG[:GRIPPER_JOINT],
        (min(closed_deg, open_deg), max(closed_deg, open_deg)),
    )


def gripper_opening(angle_deg: float, closed_deg: float, open_deg: float) -> float:
    """How open the gripper is, 0 closed .. 1 open (clipped), whichever way it reads."""
    opening = (angle_deg - closed_deg) / (open_deg - closed_deg)
    return min(max(opening, 0.0), 1.0)
