"""The G1 humanoid's body in the world: where each G1 stands and where each of its links is at a
lowstate. The one place this is computed, for the viewer (viewer/g1_scene.py draws it) and for
Foxglove and recordings (frames3d.py turns it into transforms), so both show one pose.

The model is Unitree's g1_29dof kinematics (assets/g1_29dof.urdf, primitives only), the columns
of ``q`` its 29 revolute joints in Unitree's motor order (the order of ``G1LowState.q_rad``).
The pelvis stays at its standing height above the G1's floor point, turned by its yaw and tilted
by the IMU's roll and pitch: we do not know where the robot walked (no odometry), so the picture
shows the joints and the state, not the position.

Pure: no transport, no clock, no drawing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
import yourdfpy

from fleet.g1.messages import G1LowState
from fleet.scene3d.kinematics import URDF_PATH, ArmModel, base_transforms, forward, load_urdf

FloatArray = npt.NDArray[np.float64]

G1_URDF_PATH = URDF_PATH.parent / "g1_29dof.urdf"
SPACING_M = 1.0
"""G1s without ``base_xyz`` stand this far apart, this far to the left of the arms."""
SOLE_M = 0.045
"""The foot boxes' half height below the ankle roll link: the soles touch the floor."""


class G1Placement(Protocol):
    """Where a G1 stands: an inventory's ``G1Config`` or a recording's ``DevicePlacement``."""

    @property
    def base_xyz(self) -> Sequence[float] | None: ...
    @property
    def base_yaw_deg(self) -> float: ...


def floor_points(
    placements: Sequence[G1Placement], arm_xyz: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(G, 3) floor points and (G,) yaw (deg): each G1's own, or a row left of the arms."""
    x0 = float(arm_xyz[:, 0].mean()) if len(arm_xyz) else 0.0
    y0 = (float(arm_xyz[:, 1].max()) if len(arm_xyz) else 0.0) + SPACING_M
    xyz = np.array(
        [
            tuple(p.base_xyz) if p.base_xyz is not None else (x0 + k * SPACING_M, y0, 0.0)
            for k, p in enumerate(placements)
        ],
        dtype=float,
    ).reshape(-1, 3)
    return xyz, np.array([p.base_yaw_deg for p in placements], dtype=float)


def pose_of(low: G1LowState) -> tuple[FloatArray, FloatArray]:
    """(29,) joint angles (rad) and (2,) IMU roll and pitch (rad) of a decoded lowstate (its
    schema bounds both: 29 and 3 finite values)."""
    return np.asarray(low.q_rad, dtype=float), np.asarray(low.imu_rpy[:2], dtype=float)


@dataclass(frozen=True)
class G1Body:
    """The G1's model and how it stands: ``world`` gives every link of G G1s in the world."""

    urdf: yourdfpy.URDF
    urdf_text: str
    model: ArmModel
    joints: tuple[str, ...]
    pelvis_height_m: float

    @classmethod
    def load(cls, path: Path = G1_URDF_PATH) -> G1Body:
        """Read the URDF once; the pelvis height puts the zero pose's soles on the floor."""
        urdf = load_urdf(path)
        joints = tuple(j.name for j in urdf.robot.joints if j.type == "revolute")
        model = ArmModel.from_urdf(urdf, q_joints=joints)
        zero = forward(model, np.zeros((1, len(joints))))[0]
        feet = [zero[i, 2, 3] for i, link in enumerate(model.links) if "ankle_roll" in link]
        return cls(urdf, path.read_text(), model, joints, -min(feet) + SOLE_M)

    def bases(self, placements: Mapping[str, G1Placement], arm_xyz: FloatArray) -> Any:
        """(G, 3) floor points and (G, 4, 4) world-from-pelvis at the standing height, yawed."""
        floor, yaw = floor_points(list(placements.values()), arm_xyz)
        zeros = np.zeros_like(yaw)
        pelvis = floor + [0.0, 0.0, self.pelvis_height_m]
        return floor, base_transforms(pelvis, np.c_[zeros, zeros, yaw])

    def pelvis(self, base: FloatArray, rp: FloatArray) -> FloatArray:
        """(G, 4, 4) world-from-pelvis: ``base`` (G, 4, 4) from ``bases`` tilted by the IMU's
        roll and pitch ``rp`` (G, 2, rad)."""
        n = len(base)
        tilt = base_transforms(np.zeros((n, 3)), np.degrees(np.c_[rp, np.zeros(n)]))
        return base @ tilt

    def world(self, base: FloatArray, q: FloatArray, rp: FloatArray) -> FloatArray:
        """(G, L, 4, 4) world-from-link of G G1s: ``base`` (G, 4, 4) from ``bases``, joints
        ``q`` (G, 29, rad) and IMU roll and pitch ``rp`` (G, 2, rad)."""
        return self.pelvis(base, rp)[:, None] @ forward(self.model, q)
