"""The G1 humanoids in the 3D scene: each drawn from Unitree's g1_29dof kinematics
(fleet/scene3d/assets/g1_29dof.urdf, primitives only) and posed live from its ``g1/<id>/lowstate``
(29 joints, rad, Unitree's motor order), tilted by its IMU's roll and pitch.

Like the arms (viewer/scene.py): one instanced mesh per link with an instance per G1, forward
kinematics for all of them in numpy, one ``server.atomic()`` per tick, a deadband so feedback
jitter never resends. The pelvis stays at its standing height (the viewer does not know where
the robot walked): the drawing shows the joints and the state, not the odometry.

Looks (the arms' colours, viewer/scene.py's legend): normal; grey when its lowstate is stale or
its link is not ok; dark grey before any state; red tint when its stop is latched. The label
says the same in words, with the FSM (seed 004's id and name, static or dynamic) and the
rt/arm_sdk weight while the fleet streams its arms.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt
import viser

from fleet.g1.config import G1Config
from fleet.g1.messages import G1LowState, G1State
from fleet.scene3d.kinematics import (
    URDF_PATH,
    ArmModel,
    base_transforms,
    forward,
    load_urdf,
    matrix_to_wxyz,
)
from viewer.meshes import LinkMesh, link_meshes
from viewer.scene import NORMAL, OFFLINE, STALE, STOPPED, tinted
from viewer.state import STALE_S, DeviceView

G1_URDF_PATH = URDF_PATH.parent / "g1_29dof.urdf"
DEADBAND_RAD = 0.002
LABEL_ABOVE_M = 0.25
"""The label floats this far above the head's top."""
SPACING_M = 1.0
"""G1s without ``base_xyz`` stand this far apart, this far to the left of the arms."""


def load_g1() -> tuple[ArmModel, list[LinkMesh], tuple[str, ...]]:
    """The G1's model (columns of ``q``: its 29 joints in motor order) and link meshes."""
    urdf = load_urdf(G1_URDF_PATH)
    joints = tuple(j.name for j in urdf.robot.joints if j.type == "revolute")
    model = ArmModel.from_urdf(urdf, q_joints=joints)
    return model, link_meshes(urdf, model.links), joints


def g1_label(device: str, code: int, state: G1State | None) -> str:
    """``h1 · fsm 500 walk, static · arms 0.80 · STOPPED``: the G1's id and state in words."""
    parts = [device]
    if state is not None:
        parts.append(f"fsm {state.fsm_id} {state.fsm_name}, {state.mode}")
        if state.arm_phase != "off":
            parts.append(f"arms {state.arm_phase} {state.arm_weight:.2f}")
    words = {NORMAL: "", STALE: "stale", OFFLINE: "no state", STOPPED: "STOPPED"}[code]
    if words:
        parts.append(words)
    return " · ".join(parts)


def g1_look(view: DeviceView) -> int:
    """The look code of one G1: no state beats stale beats stopped beats normal."""
    state = view.state
    if state is None and view.low is None:
        return OFFLINE
    if view.low_age_s > STALE_S or (state is not None and state.link != "ok"):
        return STALE
    if state is not None and state.estopped:
        return STOPPED
    return NORMAL


def placements(
    configs: Mapping[str, G1Config], arm_xyz: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(G, 3) floor points and (G,) yaw (deg): the inventory's, or a row left of the arms."""
    x0 = float(arm_xyz[:, 0].mean()) if len(arm_xyz) else 0.0
    y0 = (float(arm_xyz[:, 1].max()) if len(arm_xyz) else 0.0) + SPACING_M
    xyz = np.array(
        [
            c.base_xyz if c.base_xyz is not None else (x0 + k * SPACING_M, y0, 0.0)
            for k, c in enumerate(configs.values())
        ],
        dtype=float,
    ).reshape(-1, 3)
    return xyz, np.array([c.base_yaw_deg for c in configs.values()], dtype=float)


class G1Scene:
    """Scene nodes of every G1 of the inventory; ``render(devices)`` draws one tick (viewer
    thread only)."""

    def __init__(
        self,
        server: viser.ViserServer,
        configs: Mapping[str, G1Config],
        arm_xyz: npt.NDArray[np.float64],
    ) -> None:
        self.server = server
        self.devices = tuple(configs)
        self.model, self.meshes, self.joints = load_g1()
        n = len(self.devices)
        self._link_index = [self.model.links.index(mesh.link) for mesh in self.meshes]
        self._q = np.zeros((n, len(self.joints)))
        self._rp = np.zeros((n, 2))  # IMU roll, pitch (rad)
        floor, yaw = placements(configs, arm_xyz)
        zero = forward(self.model, np.zeros((1, len(self.joints))))[0]
        feet = [zero[i, 2, 3] for i, link in enumerate(self.model.links) if "ankle_roll" in link]
        self.pelvis_height_m = -min(feet) + 0.045  # the foot boxes' soles on the floor
        self._floor = floor
        self.base = base_transforms(
            floor + [0.0, 0.0, self.pelvis_height_m], np.c_[0 * yaw, 0 * yaw, yaw]
        )
        self._code = np.full(n, -1, dtype=np.int8)
        self._text = [""] * n
        wxyz, pos = self._poses()
        scene = server.scene
        self._links = [
            scene.add_batched_meshes_simple(
                f"/g1/{mesh.link}",
                vertices=mesh.vertices,
                faces=mesh.faces,
                batched_wxyzs=wxyz[k],
                batched_positions=pos[k],
                batched_colors=tinted(mesh.rgb, np.full(n, OFFLINE, dtype=np.int8)),
                lod="off",
                cast_shadow=False,  # a software-rendered browser (CI's) pays per shadow caster
                receive_shadow=False,
            )
            for k, mesh in enumerate(self.meshes)
        ]
        self._labels = [
            scene.add_label(f"/g1_labels/{device}", device, position=tuple(self._label_at(i)))
            for i, device in enumerate(self.devices)
        ]

    def _label_at(self, i: int) -> npt.NDArray[np.float64]:
        return self._floor[i] + [0.0, 0.0, self.pelvis_height_m + 0.55 + LABEL_ABOVE_M]

    def _world(self) -> npt.NDArray[np.float64]:
        """(G, L, 4, 4) world-from-link of every G1 at its drawn joints and tilt."""
        n = len(self.devices)
        rpy_deg = np.degrees(np.c_[self._rp, np.zeros(n)])
        tilt = base_transforms(np.zeros((n, 3)), rpy_deg)
        return (self.base @ tilt)[:, None] @ forward(self.model, self._q)

    def _poses(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        world = self._world()[:, self._link_index]
        wxyz = matrix_to_wxyz(world[..., :3, :3]).transpose(1, 0, 2)
        return wxyz, world[..., :3, 3].transpose(1, 0, 2)

    def frame_points(self) -> npt.NDArray[np.float64]:
        """(M, 3) points the camera must see: every G1's link origins and its label."""
        world = self._world()
        labels = np.array([self._label_at(i) for i in range(len(self.devices))]).reshape(-1, 3)
        return np.vstack([world[..., :3, 3].reshape(-1, 3), labels])

    def render(self, views: Sequence[DeviceView]) -> bool:
        """Draw the G1s among ``views`` if anything visible changed; True when sent."""
        by_id = {v.device: v for v in views}
        q, rp = self._q.copy(), self._rp.copy()
        code = self._code.copy()
        states: list[G1State | None] = []
        for i, device in enumerate(self.devices):
            view = by_id.get(device)
            state = view.state if view is not None and isinstance(view.state, G1State) else None
            states.append(state)
            code[i] = OFFLINE if view is None else g1_look(view)
            low = None if view is None else view.low
            if isinstance(low, G1LowState) and len(low.q_rad) == len(self.joints):
                row = np.asarray(low.q_rad, dtype=float)
                if np.all(np.isfinite(row)):
                    q[i] = row
                if len(low.imu_rpy) == 3 and np.all(np.isfinite(low.imu_rpy)):
                    rp[i] = low.imu_rpy[:2]
        moved = np.any(np.abs(q - self._q) > DEADBAND_RAD, axis=1) | np.any(
            np.abs(rp - self._rp) > DEADBAND_RAD, axis=1
        )
        text = [g1_label(d, int(code[i]), states[i]) for i, d in enumerate(self.devices)]
        recolour = code != self._code
        relabel = [i for i in range(len(self.devices)) if text[i] != self._text[i]]
        if not (moved.any() or recolour.any() or relabel):
            return False
        self._q[moved], self._rp[moved] = q[moved], rp[moved]
        with self.server.atomic():
            if moved.any():
                wxyz, pos = self._poses()
                for k, handle in enumerate(self._links):
                    handle.batched_wxyzs = wxyz[k]
                    handle.batched_positions = pos[k]
            if recolour.any():
                for mesh, handle in zip(self.meshes, self._links, strict=True):
                    handle.batched_colors = tinted(mesh.rgb, code)
            for i in relabel:
                self._labels[i].text = text[i]
        self._code, self._text = code, text
        return True
