"""Joint facts of the D1-550 that the codec, the agent, the simulator and the viewer share.

The wire carries seven values, ``angle0`` .. ``angle6``, all in degrees. ``angle0``..``angle5``
are the six arm joints with the ranges of the service interface's "Range of Motion" table.

``angle6`` is the gripper. The service interface names it an angle like the others and gives no
unit or range for it; the only documented figure is the claw stroke of 0-65 mm. We therefore
treat ``angle6`` as degrees of the gripper servo, 0 = closed, and accept 0..65: the stroke is
the only bound the spec gives, and a conservative envelope is safer than none. On a real arm,
measure the open and closed readings and adjust ``GRIPPER_RANGE_DEG`` if they differ; the viewer
maps this range linearly onto the URDF's 0..0.033 m finger travel.
"""

from __future__ import annotations

JOINT_COUNT = 7
"""Six arm joints plus the gripper (wire ids 0..6)."""

GRIPPER_JOINT = 6

ARM_JOINT_LIMIT_DEG: tuple[float, ...] = (135.0, 90.0, 90.0, 135.0, 90.0, 135.0)
"""Symmetric limits (+/-) of joints 0..5 from the spec's range-of-motion table."""

GRIPPER_RANGE_DEG: tuple[float, float] = (0.0, 65.0)

JOINT_RANGE_DEG: tuple[tuple[float, float], ...] = (
    *((-lim, lim) for lim in ARM_JOINT_LIMIT_DEG),
    GRIPPER_RANGE_DEG,
)
"""(min, max) per wire joint id, degrees."""

TORQUE_MODE_MAX = 80000
"""All-joint enable (1/5) ``mode``: 0 fully unloaded .. 80000 fully locked; 1 is "enable"."""

CONTROL_RATE_HZ = 10.0
"""The arm's control cycle and feedback rate."""
