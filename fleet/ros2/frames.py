"""An arm's joints as ROS TF frames, in plain Python. Pure: no I/O, no numpy.

One arm's eight moving joints cost a few microseconds this way; the viewer's vectorised numpy
kinematics (``fleet/scene3d/kinematics.py``, built for 200 arms at once) costs a millisecond
per call on one arm, which was most of ``fleet ros2``'s time per sample (a profile). The
numbers are the same: ``tests/test_ros2_frames.py`` checks both against each other.

As robot_state_publisher does, fixed joints are ``/tf_static`` (sent once) and only the moving
ones are ``/tf`` (per sample). A joint's transform parent -> child is its URDF origin times its
motion: a rotation about ``axis`` by ``q`` (revolute) or a slide along it (prismatic).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
"""x, y, z, w (ROS's order)."""
Pose = tuple[float, float, float, float, float, float, float]
"""x, y, z, qx, qy, qz, qw: a TransformStamped's numbers in wire order."""

FINGER_TRAVEL_M = 0.033
"""As fleet/scene3d/kinematics.py: the URDF's finger joints run 0 (open) .. 0.033 m (closed)."""


@dataclass(frozen=True)
class JointFrame:
    """One URDF joint: parent and child link, origin (``xyz`` and ``xyzw``), ``kind``
    (``revolute``, ``prismatic`` or ``fixed``), unit ``axis`` and the column of ``q`` that
    drives it (-1: none)."""

    parent: str
    child: str
    xyz: Vec3
    xyzw: Quat
    kind: str
    axis: Vec3
    q_index: int


def quat_mul(a: Quat, b: Quat) -> Quat:
    """The Hamilton product ``a * b`` (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def rotate(q: Quat, v: Vec3) -> Vec3:
    """``v`` rotated by the unit quaternion ``q``."""
    x, y, z, _w = quat_mul(quat_mul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


class ArmTree:
    """The fixed and the moving joints of one arm's URDF."""

    def __init__(self, joints: Sequence[JointFrame]) -> None:
        self.fixed = tuple(j for j in joints if j.kind == "fixed")
        self.moving = tuple(j for j in joints if j.kind != "fixed")
        # A prismatic joint slides along its axis in the parent frame: the origin's rotation of
        # the axis, computed once.
        self._slide = tuple(rotate(j.xyzw, j.axis) for j in self.moving)

    def static_poses(self) -> list[Pose]:
        """Each fixed joint's parent -> child, in the order of ``fixed``."""
        return [(*j.xyz, *j.xyzw) for j in self.fixed]

    def poses(self, q: Sequence[float]) -> list[Pose]:
        """Each moving joint's parent -> child at joint values ``q``, in the order of
        ``moving``."""
        out: list[Pose] = []
        sin, cos = math.sin, math.cos
        for joint, slide in zip(self.moving, self._slide, strict=True):
            value = q[joint.q_index]
            x, y, z = joint.xyz
            if joint.kind == "revolute":
                # origin * (axis sin(v/2), cos(v/2)), the Hamilton product written out
                s, c = sin(0.5 * value), cos(0.5 * value)
                ax, ay, az = joint.axis
                bx, by, bz = ax * s, ay * s, az * s
                ox, oy, oz, ow = joint.xyzw
                out.append(
                    (
                        x,
                        y,
                        z,
                        ow * bx + ox * c + oy * bz - oz * by,
                        ow * by - ox * bz + oy * c + oz * bx,
                        ow * bz + ox * by - oy * bx + oz * c,
                        ow * c - ox * bx - oy * by - oz * bz,
                    )
                )
            else:
                sx, sy, sz = slide
                out.append((x + value * sx, y + value * sy, z + value * sz, *joint.xyzw))
        return out


def wire_to_q(
    angles_deg: Sequence[float], joint_sign: Sequence[float], gripper_deg: tuple[float, float]
) -> list[float]:
    """One arm's 7 wire angles -> its 8 URDF joint values (radians, then the two fingers in
    metres), as ``fleet.scene3d.kinematics.wire_to_q`` defines it for arrays (the definition,
    with the why, is there; this is its one-arm form and is tested equal to it)."""
    k = math.pi / 180.0
    a = angles_deg
    q = [joint_sign[i] * a[i] * k for i in range(6)]
    closed, fully_open = gripper_deg
    opening = min(max((angles_deg[6] - closed) / (fully_open - closed), 0.0), 1.0)
    if joint_sign[6] < 0:
        opening = 1.0 - opening
    finger = FINGER_TRAVEL_M * (1.0 - opening)
    return [*q, finger, finger]
