"""The devices' joints as ROS names. Pure.

The G1's ``g1/<id>/lowstate`` carries its 29 motors in Unitree's order (legs 0-11, waist 12-14,
left arm 15-21, right arm 22-28: ``fleet/g1/arms.py``); its ROS joint names are those of
Unitree's ``g1_29dof`` URDF (``<motor>_joint``), so a RobotModel of that URDF moves with it. The
Dex1-1 has one motor: its joint state is that motor (``<id>_joint``, ``q_rad`` 0 closed .. 2 pi
open, with its velocity and torque estimate), not the fingers' slides of a gripper URDF.
"""

from __future__ import annotations

from fleet.g1 import arms

_LEG = ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")
G1_JOINTS: tuple[str, ...] = (
    *(f"{side}_{name}_joint" for side in ("left", "right") for name in _LEG),
    *(f"{name}_joint" for name, _lower, _upper in arms.JOINTS),
)
"""rt/lowstate's motors 0..28, as the g1_29dof URDF names their joints."""


def gripper_joints(device: str) -> tuple[str]:
    """The Dex1-1 ``device``'s one joint."""
    return (f"{device}_joint",)
