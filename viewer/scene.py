"""The 3D scene: every inventory arm at its base pose, drawn with one instanced mesh per link.

Why instanced meshes: viser's ``ViserUrdf.update_cfg`` costs about 2 ms per arm per update (one
scene node per link per arm); here each link is one ``add_batched_meshes_simple`` node with an
instance per arm, and forward kinematics runs for the whole fleet in numpy. A tick sends at most
two small arrays per link, inside one ``server.atomic()`` so the browser never sees half a tick.

Arm looks: normal colours; grey when stale (no fresh joints, link not ok); dark grey when
offline (no agent token); red tint when stopped; a red ball above an arm in error. The label
says the same in words.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Protocol

import numpy as np
import numpy.typing as npt
import viser

from fleet.d1.limits import GRIPPER_JOINT
from fleet.scene3d.kinematics import (
    ArmModel,
    base_transforms,
    forward,
    matrix_to_wxyz,
    wire_to_q,
)
from viewer.camera import (
    DEFAULT_ASPECT,
    DEFAULT_WIDTH_PX,
    FOV_RAD,
    fit_view,
    usable_right_edge,
)
from viewer.meshes import LinkMesh
from viewer.reach import reach_points
from viewer.state import STALE_S, Snapshot

DEADBAND_DEG = 0.05
"""Joint changes smaller than this are not drawn (feedback jitter would resend every tick)."""

LABEL_HEIGHT_M = 0.72
"""The highest a label goes above its base (an arm reaching straight up); framing uses it."""
LABEL_ABOVE_M = 0.12
"""A label floats this far above its arm's highest link origin (the link's own shape below it)."""
LABEL_STEP_M = 0.02
"""A label moves only when its height changes by more than this (no resend per sample)."""
ERROR_MARK_HEIGHT_M = 0.64

# Look codes per arm, in priority order (the first that applies wins).
NORMAL, STALE, OFFLINE, STOPPED = 0, 1, 2, 3
STALE_RGB = np.array([170, 170, 170], dtype=float)
OFFLINE_RGB = np.array([85, 85, 90], dtype=float)
STOP_RGB = np.array([230, 30, 30], dtype=float)
CONTACT_RGB = np.array([255, 170, 0], dtype=float)
"""A link whose joint is in confirmed contact is drawn in this amber, whatever the arm's look."""


def looks(snapshot: Snapshot) -> npt.NDArray[np.int8]:
    """(N,) look code per arm: offline beats stale beats stopped beats normal."""
    code = np.full(len(snapshot.arms), NORMAL, dtype=np.int8)
    code[snapshot.estopped] = STOPPED
    code[snapshot.stale] = STALE
    code[~snapshot.online] = OFFLINE
    return code


def tinted(rgb: tuple[int, int, int], code: npt.NDArray[np.int8]) -> npt.NDArray[np.uint8]:
    """(N, 3) instance colours of one link for the arms' look codes."""
    base = np.asarray(rgb, dtype=float)
    out = np.tile(base, (len(code), 1))
    out[code == STALE] = 0.35 * base + 0.65 * STALE_RGB
    out[code == OFFLINE] = 0.15 * base + 0.85 * OFFLINE_RGB
    out[code == STOPPED] = 0.45 * base + 0.55 * STOP_RGB
    return np.clip(out, 0, 255).astype(np.uint8)


ERROR_RGB = (230, 20, 20)
"""The ball above an arm in error."""

LEGEND = (
    (STALE_RGB, "stale", f"no joints for {STALE_S:g} s, or the agent reports the link not ok"),
    (OFFLINE_RGB, "OFFLINE", "the arm's agent is gone (its liveliness token vanished)"),
    (STOP_RGB, "STOPPED", "a protective stop is latched: only a reset releases it"),
    (CONTACT_RGB, "contact", "that link's joint is in confirmed contact (amber, any look)"),
    (ERROR_RGB, "red ball", "above an arm: the arm reports an error (its label says ERROR)"),
)


def legend_html() -> str:
    """What every colour of the scene means (built from the colours themselves)."""
    rows = "".join(
        f"<div><span style='display:inline-block;width:0.9em;height:0.9em;"
        f"background:#{int(r):02x}{int(g):02x}{int(b):02x};margin-right:6px'></span>"
        f"<b>{word}</b>: {meaning}</div>"
        for (r, g, b), word, meaning in LEGEND
    )
    normal = "<div>the links' own colours: normal, everything fresh and ok</div>"
    return f"<div id='legend' style='font-size:0.8em'>{normal}{rows}</div>"


def label_text(arm: str, code: int, error: bool) -> str:
    """The arm's label: its id and, when not normal, its state in words."""
    words = {NORMAL: "", STALE: "stale", OFFLINE: "OFFLINE", STOPPED: "STOPPED"}[code]
    if error:
        words = f"{words} ERROR".strip()
    return f"{arm} · {words}" if words else arm


class Placement(Protocol):
    """Where an arm stands: an inventory's ``ArmConfig`` or a recording's ``ArmPlacement``."""

    @property
    def base_xyz(self) -> Sequence[float]: ...
    @property
    def base_rpy_deg(self) -> Sequence[float]: ...
    @property
    def joint_sign(self) -> Sequence[int]: ...
    @property
    def gripper_closed_deg(self) -> float: ...
    @property
    def gripper_open_deg(self) -> float: ...


class FleetScene:
    """Scene nodes of the whole fleet; ``render(snapshot)`` draws one tick (viewer thread only);
    ``fit`` frames the fleet in browsers (any thread)."""

    def __init__(
        self,
        server: viser.ViserServer,
        placements: Mapping[str, Placement],
        model: ArmModel,
        meshes: list[LinkMesh],
    ) -> None:
        self.server = server
        self.model = model
        self.arms = tuple(placements)
        self._index = {arm: i for i, arm in enumerate(self.arms)}
        configs = [placements[a] for a in self.arms]
        self.joint_sign = np.array([c.joint_sign for c in configs], dtype=float)
        self.gripper_deg = np.array(
            [(c.gripper_closed_deg, c.gripper_open_deg) for c in configs], dtype=float
        )
        xyz = np.array([c.base_xyz for c in configs], dtype=float)
        self.base = base_transforms(xyz, [c.base_rpy_deg for c in configs])
        self.meshes = meshes
        self._link_index = [model.links.index(mesh.link) for mesh in meshes]
        # Wire joint that moves each drawn link (q columns 6 and 7 are the gripper's fingers).
        self._link_joint = [
            min(model.q_index[i], GRIPPER_JOINT) if model.q_index[i] >= 0 else -1
            for i in self._link_index
        ]
        n = len(self.arms)
        self._drawn_deg = np.zeros((n, 7))
        self._drawn_code = np.full(n, -1, dtype=np.int8)
        self._drawn_error = np.zeros(n, dtype=bool)
        self._drawn_contact = np.zeros((n, 7), dtype=bool)
        self.more_points: list[Callable[[], npt.NDArray[np.float64]]] = []

        scene = server.scene
        scene.set_up_direction("+z")
        # No shadow maps: each light's depth pass per frame kept a software-rendered page (a
        # lab PC without a GPU, CI's Chromium) at 0.55-0.64 of a core while idle; 0.20 without.
        scene.configure_default_lights(cast_shadow=False)
        span = float(np.max(np.abs(xyz[:, :2]))) if n else 0.0
        size = 2.0 * (np.ceil(span) + 1.0)
        scene.add_grid("/ground", width=size, height=size, plane="xy", cell_size=0.1)
        scene.add_frame("/world", axes_length=0.15, axes_radius=0.006)
        wxyz, pos = self._poses(np.zeros((n, 7)))
        self._corners = np.stack([_box_corners(mesh.vertices) for mesh in meshes])  # (K, 8, 3)
        self.reach = self._reach_points(configs)
        self._set_initial_camera()
        self._links = [
            scene.add_batched_meshes_simple(
                f"/fleet/{mesh.link}",
                vertices=mesh.vertices,
                faces=mesh.faces,
                batched_wxyzs=wxyz[k],
                batched_positions=pos[k],
                batched_colors=tinted(mesh.rgb, np.zeros(n, dtype=np.int8)),
                lod="off",
            )
            for k, mesh in enumerate(meshes)
        ]
        top = xyz + np.array([0.0, 0.0, ERROR_MARK_HEIGHT_M])
        self._error_marks = scene.add_batched_meshes_simple(
            "/fleet/error_marks",
            vertices=_ball()[0],
            faces=_ball()[1],
            batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
            batched_positions=top,
            batched_scales=np.zeros(n),
            batched_colors=ERROR_RGB,
            lod="off",
        )
        self._labels = [
            scene.add_label(
                f"/labels/{arm}", arm, position=tuple(xyz[i] + [0.0, 0.0, LABEL_HEIGHT_M])
            )
            for i, arm in enumerate(self.arms)
        ]
        self._label_z = np.full(n, np.nan)  # drawn label heights above the base (nan: not yet)

    def _reach_points(self, configs: Sequence[Placement]) -> npt.NDArray[np.float64]:
        """(M, 3) world points around every arm's reach (viewer/reach.py): arms that share a
        joint sign and gripper reading share one hull, turned to each base."""
        hulls: dict[tuple[tuple[float, ...], tuple[float, float]], npt.NDArray[np.float64]] = {}
        out = []
        for i in range(len(self.arms)):
            key = (tuple(self.joint_sign[i]), (self.gripper_deg[i, 0], self.gripper_deg[i, 1]))
            if key not in hulls:
                hulls[key] = reach_points(
                    self.model, self._link_index, self._corners, key[0], key[1]
                )
            hull = hulls[key]
            out.append(hull @ self.base[i, :3, :3].T + self.base[i, :3, 3])
        return np.vstack(out) if out else np.zeros((0, 3))

    def view_points(self) -> npt.NDArray[np.float64]:
        """(M, 3) points the camera frames (at start and on "Fit view"): every arm's whole reach
        and its label at its highest, so an arm at any pose its joint limits allow stays in
        view; the same whatever pose the arms are in now; and what other scenes add
        (``frame_also``: each G1's body)."""
        labels = self.base[:, :3, 3] + [0.0, 0.0, LABEL_HEIGHT_M + 0.03]
        extra = [points() for points in self.more_points]
        return np.vstack([self.reach, labels, *extra])

    def _set_initial_camera(self) -> None:
        """Where a new browser's camera starts (and viser's "reset view" returns to)."""
        camera = self.server.initial_camera
        camera.fov = FOV_RAD
        right = usable_right_edge(DEFAULT_WIDTH_PX)
        position, target = fit_view(self.view_points(), FOV_RAD, DEFAULT_ASPECT, right)
        camera.position = tuple(position)
        camera.look_at = tuple(target)

    def frame_points(self, angles_deg: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """(M, 3) the corners of every link's bounding box, each arm at ``angles_deg`` (N, 7),
        and every arm's label."""
        q = wire_to_q(angles_deg, self.joint_sign, self.gripper_deg)
        world = self.base[:, None] @ forward(self.model, q)[:, self._link_index]  # (N, K, 4, 4)
        corners = np.einsum("nkij,kcj->nkci", world[..., :3, :3], self._corners)
        labels = self.base[:, :3, 3] + [0.0, 0.0, LABEL_HEIGHT_M + 0.03]
        extra = [points() for points in self.more_points]
        return np.vstack([(corners + world[..., None, :3, 3]).reshape(-1, 3), labels, *extra])

    def frame_also(self, points: Callable[[], npt.NDArray[np.float64]]) -> None:
        """Frame ``points()`` too (another scene's bodies, e.g. the G1s), from now on."""
        self.more_points.append(points)
        self._set_initial_camera()

    def fit(self, client: viser.ClientHandle) -> None:
        """Frame every arm's whole reach (``view_points``) in ``client``'s view (its canvas'
        aspect, the part the control panel leaves free): the first view and "Fit view" alike."""
        camera = client.camera
        camera.fov = FOV_RAD
        right = usable_right_edge(camera.image_width)
        position, target = fit_view(self.view_points(), FOV_RAD, camera.aspect, right)
        camera.up_direction = (0.0, 0.0, 1.0)
        # position first: viser moves look_at with it; then look_at turns the camera in place
        camera.position = tuple(position)
        camera.look_at = tuple(target)

    def _poses(
        self, angles_deg: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """(K links, N, 4) orientations and (K, N, 3) positions in the world."""
        q = wire_to_q(angles_deg, self.joint_sign, self.gripper_deg)
        world = self.base[:, None] @ forward(self.model, q)[:, self._link_index]
        wxyz = matrix_to_wxyz(world[..., :3, :3]).transpose(1, 0, 2)
        return wxyz, world[..., :3, 3].transpose(1, 0, 2)

    def _place_labels(self, pos: npt.NDArray[np.float64]) -> None:
        """Each label (and error ball) just above its arm's highest link as drawn, not an
        arm-height above a folded arm; moved only by more than ``LABEL_STEP_M``."""
        base = self.base[:, :3, 3]
        above = np.minimum(pos[:, :, 2].max(axis=0) - base[:, 2] + LABEL_ABOVE_M, LABEL_HEIGHT_M)
        changed = ~(np.abs(above - self._label_z) <= LABEL_STEP_M)  # nan: never placed
        if not changed.any():
            return
        self._label_z[changed] = above[changed]
        for i in np.flatnonzero(changed):
            self._labels[i].position = tuple(base[i] + [0.0, 0.0, above[i]])
        below_label = ERROR_MARK_HEIGHT_M - LABEL_HEIGHT_M  # the ball sits under its label
        marks = base.copy()
        marks[:, 2] += above + below_label
        self._error_marks.batched_positions = marks

    def drawn_angles(self, snapshot: Snapshot) -> npt.NDArray[np.float64]:
        """(N, 7) the angles to draw: the arms' own, with a mounted gripper's opening (a
        Dex1-1 on the arm: ``opening_pct``) driving that arm's fingers instead of ``angle6``."""
        angles = snapshot.angles_deg
        mounted = [
            (self._index[v.mount], float(v.state.opening_pct))
            for v in snapshot.devices
            if v.mount in self._index and v.state is not None and hasattr(v.state, "opening_pct")
        ]
        if not mounted:
            return angles
        angles = angles.copy()
        for i, pct in mounted:
            closed, fully_open = self.gripper_deg[i]
            angles[i, GRIPPER_JOINT] = closed + min(max(pct, 0.0), 100.0) / 100.0 * (
                fully_open - closed
            )
        return angles

    def render(self, snapshot: Snapshot) -> bool:
        """Draw ``snapshot`` if anything visible changed; True when something was sent."""
        angles = self.drawn_angles(snapshot)
        moved = np.any(np.abs(angles - self._drawn_deg) > DEADBAND_DEG, axis=1)
        code = looks(snapshot)
        error = snapshot.error
        contact = snapshot.contact_rows()
        recolour = (code != self._drawn_code) | np.any(contact != self._drawn_contact, axis=1)
        relabel = recolour | (error != self._drawn_error)
        if not (moved.any() or relabel.any()):
            return False
        # Arms inside the deadband keep their drawn angles, so the jitter never accumulates.
        self._drawn_deg[moved] = angles[moved]
        with self.server.atomic():
            if moved.any():
                wxyz, pos = self._poses(self._drawn_deg)
                for k, handle in enumerate(self._links):
                    if self.model.parent[self._link_index[k]] == -1:
                        continue  # the base never moves
                    handle.batched_wxyzs = wxyz[k]
                    handle.batched_positions = pos[k]
                self._place_labels(pos)
            if recolour.any():
                for k, (mesh, handle) in enumerate(zip(self.meshes, self._links, strict=True)):
                    colors = tinted(mesh.rgb, code)
                    joint = self._link_joint[k]
                    if joint >= 0:
                        colors[contact[:, joint]] = CONTACT_RGB.astype(np.uint8)
                    handle.batched_colors = colors
            if relabel.any():
                self._error_marks.batched_scales = error.astype(float)
                for i in np.flatnonzero(relabel):
                    self._labels[i].text = label_text(self.arms[i], int(code[i]), bool(error[i]))
        self._drawn_code = code
        self._drawn_error = error
        self._drawn_contact = contact
        return True


def _box_corners(vertices: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
    """The 8 corners of the axis-aligned box around ``vertices`` (in the link's frame)."""
    low, high = vertices.min(axis=0).astype(float), vertices.max(axis=0).astype(float)
    pick = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], dtype=bool)
    return np.where(pick, high, low)


def _ball() -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]]:
    """A small icosahedron (the error mark)."""
    t = (1.0 + 5**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t]]
        + [[0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float32,
    )
    v *= 0.035 / np.linalg.norm(v[0])
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4]]
        + [[11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8]]
        + [[3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.uint32,
    )
    return v, f
