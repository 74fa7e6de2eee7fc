"""Wire angles -> URDF joint values, and vectorised forward kinematics for many arms at once.

This is the one place where the key space's ``angles_deg`` (wire ids 0..6, degrees) become the
URDF's joint values (``q``: radians for Joint1..Joint6, metres for the two fingers):

- ``angle0..angle5`` -> ``Joint1..Joint6``: ``q_rad = joint_sign[i] * radians(angle_deg[i])``.
  ``joint_sign`` is the inventory's per-arm setting (field reports, unverified, say servos 0 and 3
  turn opposite to the URDF joints; the default is +1 everywhere).
- ``angle6`` (gripper; per arm, ``angle6`` reads ``gripper_closed_deg`` closed and
  ``gripper_open_deg`` open, by default 0 and 65, see fleet/d1/limits.py) -> ``Joint_L`` and
  ``Joint_R``, linearly over 0..0.033 m. Both finger axes point towards the gripper's centre, so
  the URDF's 0 m is open and 0.033 m closed: ``q_finger = 0.033 * (1 - opening)`` with
  ``opening = (angle6 - closed) / (open - closed)`` clipped to 0..1. ``joint_sign[6] = -1``
  (older inventories' way to say the servo reads the other way round) flips it once more.

Forward kinematics works on arrays of shape (N arms, ...): one matrix product per joint for the
whole fleet, no Python loop over arms (the viewer draws 200 arms at 10-30 Hz).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import yourdfpy

from fleet.d1.limits import GRIPPER_JOINT, GRIPPER_RANGE_DEG, JOINT_COUNT

FloatArray = npt.NDArray[np.float64]

URDF_PATH = Path(__file__).resolve().parent / "assets" / "d1_550.urdf"

ARM_JOINTS = ("Joint1", "Joint2", "Joint3", "Joint4", "Joint5", "Joint6")
"""URDF joints of wire ids 0..5, in order."""
FINGER_JOINTS = ("Joint_L", "Joint_R")
"""URDF joints driven by wire id 6 (the gripper)."""
Q_JOINTS = (*ARM_JOINTS, *FINGER_JOINTS)
"""The order of the columns of ``q`` (as ``wire_to_q`` returns it)."""
FINGER_TRAVEL_M = 0.033


def load_urdf(path: Path = URDF_PATH) -> yourdfpy.URDF:
    """The D1-550 URDF (primitives only: no mesh files, no downloads)."""
    return yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)


@dataclass(frozen=True)
class ArmModel:
    """The kinematic tree of one arm as arrays, links in topological order (root first).

    ``parent[i]`` is the index of link i's parent link (-1 for the root); ``origin[i]`` the
    fixed transform parent -> joint frame; ``axis[i]`` the joint axis; ``kind[i]`` "revolute",
    "prismatic" or "fixed"; ``q_index[i]`` the column of ``q`` that drives it (-1: none).
    """

    links: tuple[str, ...]
    parent: tuple[int, ...]
    origin: FloatArray  # (L, 4, 4)
    axis: FloatArray  # (L, 3)
    kind: tuple[str, ...]
    q_index: tuple[int, ...]

    @classmethod
    def from_urdf(cls, urdf: yourdfpy.URDF, q_joints: tuple[str, ...] = Q_JOINTS) -> ArmModel:
        """Read the chain from a loaded URDF (the file is the source of truth); ``q_joints``:
        the joints driven by the columns of ``q``, in order (the D1's by default)."""
        child_joint = {j.child: j for j in urdf.robot.joints}
        roots = [link.name for link in urdf.robot.links if link.name not in child_joint]
        if len(roots) != 1:
            raise ValueError(f"the URDF must have exactly one root link, found {roots}")
        root = roots[0]
        links, parent, origins, axes, kinds, q_index = [root], [-1], [np.eye(4)], [], [], [-1]
        axes.append(np.zeros(3))
        kinds.append("fixed")
        frontier = [root]
        while frontier:
            name = frontier.pop(0)
            for joint in urdf.robot.joints:
                if joint.parent != name:
                    continue
                links.append(joint.child)
                parent.append(links.index(name))
                origins.append(np.eye(4) if joint.origin is None else np.asarray(joint.origin))
                axis = np.zeros(3) if joint.axis is None else np.asarray(joint.axis, dtype=float)
                axes.append(axis / max(float(np.linalg.norm(axis)), 1e-12))
                kinds.append(joint.type if joint.type in ("revolute", "prismatic") else "fixed")
                q_index.append(q_joints.index(joint.name) if joint.name in q_joints else -1)
                frontier.append(joint.child)
        return cls(
            links=tuple(links),
            parent=tuple(parent),
            origin=np.stack(origins),
            axis=np.stack(axes),
            kind=tuple(kinds),
            q_index=tuple(q_index),
        )


def wire_to_q(
    angles_deg: npt.ArrayLike,
    joint_sign: npt.ArrayLike,
    gripper_deg: npt.ArrayLike = GRIPPER_RANGE_DEG,
) -> FloatArray:
    """(N, 7) wire angles (degrees), (N, 7) or (7,) signs and (N, 2) or (2,) gripper readings
    (closed, open) -> (N, 8) URDF joint values."""
    angles = np.atleast_2d(np.asarray(angles_deg, dtype=float))
    if angles.shape[-1] != JOINT_COUNT:
        raise ValueError(f"expected {JOINT_COUNT} wire angles per arm, got {angles.shape[-1]}")
    sign = np.broadcast_to(np.asarray(joint_sign, dtype=float), angles.shape)
    q = np.empty((angles.shape[0], len(Q_JOINTS)))
    q[:, : len(ARM_JOINTS)] = np.radians(angles[:, : len(ARM_JOINTS)] * sign[:, : len(ARM_JOINTS)])
    gripper = np.broadcast_to(np.asarray(gripper_deg, dtype=float), (angles.shape[0], 2))
    closed, fully_open = gripper[:, 0], gripper[:, 1]
    opening = np.clip((angles[:, GRIPPER_JOINT] - closed) / (fully_open - closed), 0.0, 1.0)
    opening = np.where(sign[:, GRIPPER_JOINT] < 0, 1.0 - opening, opening)
    q[:, len(ARM_JOINTS) :] = (FINGER_TRAVEL_M * (1.0 - opening))[:, None]
    return q


def _axis_rotations(axis: FloatArray, angle: FloatArray) -> FloatArray:
    """Rodrigues: rotations about one unit ``axis`` by N angles -> (N, 3, 3)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def forward(model: ArmModel, q: FloatArray) -> FloatArray:
    """(N, Q) joint values -> (N, L, 4, 4) transforms of every link in the arm's base frame."""
    n = q.shape[0]
    out = np.empty((n, len(model.links), 4, 4))
    out[:, 0] = np.eye(4)
    for i in range(1, len(model.links)):
        local = np.broadcast_to(model.origin[i], (n, 4, 4)).copy()
        if model.kind[i] != "fixed":
            value = q[:, model.q_index[i]]
            motion = np.tile(np.eye(4), (n, 1, 1))
            if model.kind[i] == "revolute":
                motion[:, :3, :3] = _axis_rotations(model.axis[i], value)
            else:
                motion[:, :3, 3] = value[:, None] * model.axis[i]
            local = local @ motion
        out[:, i] = out[:, model.parent[i]] @ local
    return out


def base_transforms(xyz: npt.ArrayLike, rpy_deg: npt.ArrayLike) -> FloatArray:
    """(N, 3) positions and (N, 3) roll-pitch-yaw (degrees, URDF convention: R = Rz Ry Rx)
    -> (N, 4, 4) world-from-base transforms."""
    xyz = np.atleast_2d(np.asarray(xyz, dtype=float))
    r, p, y = np.radians(np.atleast_2d(np.asarray(rpy_deg, dtype=float))).T
    rx = _axis_rotations(np.array([1.0, 0.0, 0.0]), r)
    ry = _axis_rotations(np.array([0.0, 1.0, 0.0]), p)
    rz = _axis_rotations(np.array([0.0, 0.0, 1.0]), y)
    out = np.tile(np.eye(4), (xyz.shape[0], 1, 1))
    out[:, :3, :3] = rz @ ry @ rx
    out[:, :3, 3] = xyz
    return out


def matrix_to_wxyz(rotation: FloatArray) -> FloatArray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z), branch-free
    enough for arrays: the largest of the four candidates is used per element."""
    m = rotation
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    cand = np.stack(
        [
            1.0 + m00 + m11 + m22,
            1.0 + m00 - m11 - m22,
            1.0 - m00 + m11 - m22,
            1.0 - m00 - m11 + m22,
        ],
        axis=-1,
    )
    best = np.argmax(cand, axis=-1)
    s = np.sqrt(np.maximum(np.take_along_axis(cand, best[..., None], -1)[..., 0], 1e-12)) * 2.0
    d21, d02, d10 = (
        m[..., 2, 1] - m[..., 1, 2],
        m[..., 0, 2] - m[..., 2, 0],
        m[..., 1, 0] - m[..., 0, 1],
    )
    s21, s02, s10 = (
        m[..., 2, 1] + m[..., 1, 2],
        m[..., 0, 2] + m[..., 2, 0],
        m[..., 1, 0] + m[..., 0, 1],
    )
    q = np.empty((*m.shape[:-2], 4))
    rows = [
        (0.25 * s, d21 / s, d02 / s, d10 / s),
        (d21 / s, 0.25 * s, s10 / s, s02 / s),
        (d02 / s, s10 / s, 0.25 * s, s21 / s),
        (d10 / s, s02 / s, s21 / s, 0.25 * s),
    ]
    for k, row in enumerate(rows):
        mask = best == k
        for c in range(4):
            q[..., c] = np.where(mask, row[c], q[..., c]) if k else row[c]
    return q
