"""The G1 humanoids in the 3D scene: each drawn from Unitree's g1_29dof kinematics
(fleet/scene3d/assets/g1_29dof.urdf, primitives only) and posed from its ``g1/<id>/lowstate``
(29 joints, rad, Unitree's motor order), tilted by its IMU's roll and pitch: live, or from a
recording (``fleet viewer --replay``), through the same ``render``.

Like the arms (viewer/scene.py): one instanced mesh per link with an instance per G1, forward
kinematics for all of them in numpy, one ``server.atomic()`` per tick, a deadband so feedback
jitter never resends. Where a G1 stands and where its links are is fleet/scene3d/g1_body.py's
(Foxglove shows the same pose): the pelvis at its standing height (the viewer does not know
where the robot walked), the drawing shows the joints and the state, not the odometry.

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

from fleet.g1.messages import G1LowState, G1State
from fleet.scene3d.g1_body import G1_URDF_PATH, G1Body, G1Placement, pose_of
from fleet.scene3d.kinematics import ArmModel, matrix_to_wxyz
from viewer.meshes import LinkMesh, link_meshes
from viewer.scene import NORMAL, OFFLINE, STALE, STOPPED, tinted
from viewer.state import STALE_S, DeviceView

__all__ = ["G1_URDF_PATH", "G1Scene", "g1_label", "g1_look", "load_g1"]

DEADBAND_RAD = 0.002
LABEL_ABOVE_M = 0.25
"""The label floats this far above the head's top."""


def load_g1() -> tuple[ArmModel, list[LinkMesh], tuple[str, ...]]:
    """The G1's model (columns of ``q``: its 29 joints in motor order) and link meshes."""
    body = G1Body.load()
    return body.model, link_meshes(body.urdf, body.model.links), body.joints


def g1_label(device: str, code: int, state: G1State | None) -> str:
    """``h1 · fsm 500 walk, static · arms 0.80 · STOPPED``: the G1's id and state in words."""
    parts = [device]
    if state is not None:
        parts.append(f"fsm {state.fsm_id} {state.fsm_name}, {state.mode}")
        if state.arm_phase != "off":
            weight = "?" if state.arm_weight is None else f"{state.arm_weight:.2f}"
            parts.append(f"arms {state.arm_phase} {weight}")
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


class G1Scene:
    """Scene nodes of every G1 of the inventory; ``render(devices)`` draws one tick (viewer
    thread only)."""

    def __init__(
        self,
        server: viser.ViserServer,
        placements: Mapping[str, G1Placement],
        arm_xyz: npt.NDArray[np.float64],
    ) -> None:
        """``placements``: each G1's inventory entry (live) or recorded placement (a replay)."""
        self.server = server
        self.devices = tuple(placements)
        self.body = G1Body.load()
        self.model, self.joints = self.body.model, self.body.joints
        self.meshes = link_meshes(self.body.urdf, self.model.links)
        n = len(self.devices)
        self._link_index = [self.model.links.index(mesh.link) for mesh in self.meshes]
        self._q = np.zeros((n, len(self.joints)))
        self._rp = np.zeros((n, 2))  # IMU roll, pitch (rad)
        self._floor, self.base = self.body.bases(placements, arm_xyz)
        self.pelvis_height_m = self.body.pelvis_height_m
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
        return self.body.world(self.base, self._q, self._rp)

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
            if isinstance(low, G1LowState):  # decoded: its schema bounds it (29 finite angles)
                q[i], rp[i] = pose_of(low)
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
