"""Arms and G1s in 3D for Foxglove: per unit, its URDF (link names prefixed ``<id>/``) and the
link transforms of a joints sample (an arm) or a lowstate (a G1) as Foxglove's well-known
``foxglove.FrameTransforms``.

Frames: ``world`` -> ``<id>/<root link>`` is the unit's base pose (an arm's base from the
inventory or recorded layout; a G1's pelvis where the viewer stands it, tilted by its IMU:
g1_body.py); then every URDF joint is one transform ``<id>/<parent link>`` ->
``<id>/<child link>`` computed by our forward kinematics (kinematics.py, which the viewer draws
with too), by one function for both kinds (``_tree``). Foxglove's 3D panel places the URDF
(loaded from the ``/d1/<id>/robot_description`` topic, ``{"data": urdf}``, as ROS's
``std_msgs/String`` would carry it) on those frames. Ids are unique across arms and devices
(the inventory refuses a clash), so one topic pattern serves both.

Used by the live bridge (``fleet foxglove``) and by ``fleet record``: both write the same
topics and schemas. Pure: no transport, no clock.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

from fleet.g1.messages import G1LowState
from fleet.record.layout import ArmPlacement, FleetLayout
from fleet.record.writer import DerivedMessage
from fleet.scene3d import kinematics as k
from fleet.scene3d.g1_body import G1Body, pose_of
from fleet.wire import keys

WORLD_FRAME = "world"
TOPIC_PREFIX = "/d1"
"""The 3D topics start with ``/d1/``: no Zenoh key does, so ``fleet replay`` and the replay
viewer (which read channels by key) never mistake them for key-space channels."""
URDF_SCHEMA = {
    "title": "std_msgs/String",
    "description": "The arm's or G1's URDF (links prefixed with its id) for Foxglove's 3D panel",
    "type": "object",
    "properties": {"data": {"type": "string"}},
}


def transforms_topic(unit: str) -> str:
    """The arm's or G1's FrameTransforms topic."""
    return f"{TOPIC_PREFIX}/{unit}/transforms"


def urdf_topic(unit: str) -> str:
    """The arm's or G1's URDF topic."""
    return f"{TOPIC_PREFIX}/{unit}/robot_description"


def prefixed_urdf(text: str, arm: str) -> str:
    """``text`` with every link name (and joint reference to one) prefixed ``<arm>/``, so the
    URDF's frames are the arm's own frames."""
    return re.sub(r'(<link\s+name|<parent\s+link|<child\s+link)="([^"]+)"', rf'\1="{arm}/\2"', text)


def _urdf_json(text: str, unit: str) -> bytes:
    return json.dumps({"data": prefixed_urdf(text, unit)}).encode()


def _timestamp(stamp_ns: int) -> Timestamp:
    return Timestamp(sec=stamp_ns // 1_000_000_000, nsec=stamp_ns % 1_000_000_000)


def _transform(parent: str, child: str, matrix: Any, stamp: Timestamp) -> FrameTransform:
    w, x, y, z = (float(v) for v in k.matrix_to_wxyz(np.asarray(matrix[:3, :3])))
    tx, ty, tz = (float(v) for v in matrix[:3, 3])
    return FrameTransform(
        timestamp=stamp,
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=tx, y=ty, z=tz),
        rotation=Quaternion(x=x, y=y, z=z, w=w),
    )


@dataclass(frozen=True)
class ArmFrames:
    """The 3D view of a fleet layout: URDFs and transforms per arm."""

    layout: FleetLayout
    model: k.ArmModel
    urdf_text: str

    @classmethod
    def load(cls, layout: FleetLayout, urdf_path: Path = k.URDF_PATH) -> ArmFrames:
        """Read the URDF once."""
        return cls(layout, k.ArmModel.from_urdf(k.load_urdf(urdf_path)), urdf_path.read_text())

    def urdf_message(self, arm: str) -> bytes:
        """The arm's ``{"data": urdf}`` JSON."""
        return _urdf_json(self.urdf_text, arm)

    def link_matrices(self, arm: str, angles_deg: list[float]) -> Any:
        """(L, 4, 4) world-from-link transforms of ``arm`` at ``angles_deg`` (for tests and
        anyone who wants them without the message)."""
        placement = self.layout.arms[arm]
        base = k.base_transforms(placement.base_xyz, placement.base_rpy_deg)[0]
        return base @ self._forward(placement, angles_deg)

    def _forward(self, placement: ArmPlacement, angles_deg: list[float]) -> Any:
        gripper = (placement.gripper_closed_deg, placement.gripper_open_deg)
        q = k.wire_to_q([angles_deg], placement.joint_sign, gripper)
        return k.forward(self.model, q)[0]

    def transforms(self, arm: str, angles_deg: list[float], stamp_ns: int) -> FrameTransforms:
        """The base pose and one transform per URDF joint, stamped ``stamp_ns``."""
        placement = self.layout.arms[arm]
        base = k.base_transforms(placement.base_xyz, placement.base_rpy_deg)[0]
        return _tree(arm, self.model, base, self._forward(placement, angles_deg), stamp_ns)


def _tree(unit: str, model: k.ArmModel, base: Any, links: Any, stamp_ns: int) -> FrameTransforms:
    """``world`` -> the root at ``base``, then parent -> child for every joint of ``model``
    whose (L, 4, 4) root-from-link transforms are ``links``."""
    stamp = _timestamp(stamp_ns)
    names = [f"{unit}/{name}" for name in model.links]
    out = [_transform(WORLD_FRAME, names[0], base, stamp)]
    for i in range(1, len(names)):
        parent = model.parent[i]
        local = np.linalg.solve(links[parent], links[i])  # parent-from-child
        out.append(_transform(names[parent], names[i], local, stamp))
    return FrameTransforms(transforms=out)


@dataclass(frozen=True)
class G1Frames:
    """The 3D view of a fleet layout's G1s: their URDF and transforms per G1, each standing
    where the viewer draws it (g1_body.py places both)."""

    body: G1Body
    devices: tuple[str, ...]
    base: Any  # (G, 4, 4) world-from-pelvis, standing, yawed

    @classmethod
    def load(cls, layout: FleetLayout) -> G1Frames:
        """The layout's G1s (none: an empty view; the URDF is read once all the same)."""
        body = G1Body.load()
        g1s = {d: p for d, p in layout.devices.items() if p.kind == keys.G1}
        arm_xyz = np.array([p.base_xyz for p in layout.arms.values()], dtype=float).reshape(-1, 3)
        _floor, base = body.bases(g1s, arm_xyz)
        return cls(body, tuple(g1s), base)

    def urdf_message(self, device: str) -> bytes:
        """The G1's ``{"data": urdf}`` JSON."""
        return _urdf_json(self.body.urdf_text, device)

    def link_matrices(self, device: str, low: G1LowState) -> Any:
        """(L, 4, 4) world-from-link of ``device`` at ``low`` (as the viewer draws it)."""
        i = self.devices.index(device)
        q, rp = pose_of(low)
        return self.body.world(self.base[i : i + 1], q[None], rp[None])[0]

    def transforms(self, device: str, low: G1LowState) -> FrameTransforms:
        """World -> pelvis (standing, yawed, tilted by the IMU), then one transform per joint,
        stamped with the lowstate's own stamp."""
        i = self.devices.index(device)
        q, rp = pose_of(low)
        pelvis = self.body.pelvis(self.base[i : i + 1], rp[None])[0]
        links = k.forward(self.body.model, q[None])[0]
        return _tree(device, self.body.model, pelvis, links, low.stamp_ns)


G1_LOWSTATE = f"{keys.G1}/{keys.LOWSTATE}"
"""The channel kind (``payloads.CHANNELS``) whose samples pose a G1."""


@dataclass(frozen=True)
class FleetFrames:
    """Every unit of a layout in 3D (arms and G1s): what the live bridge and ``fleet record``
    both publish, through these two methods."""

    arms: ArmFrames
    g1s: G1Frames

    @classmethod
    def load(cls, layout: FleetLayout) -> FleetFrames:
        """Read both URDFs once."""
        return cls(ArmFrames.load(layout), G1Frames.load(layout))

    @property
    def units(self) -> tuple[str, ...]:
        """The arms, then the G1s: every unit with a URDF and transforms."""
        return (*self.arms.layout.arms, *self.g1s.devices)

    def urdf_message(self, unit: str) -> bytes:
        """The unit's ``{"data": urdf}`` JSON."""
        if unit in self.arms.layout.arms:
            return self.arms.urdf_message(unit)
        return self.g1s.urdf_message(unit)

    def transforms_of(self, unit: str, channel: str, payload: Any) -> FrameTransforms | None:
        """The transforms a decoded sample poses: an arm's joints (7 angles) or a G1's
        lowstate (its schema bounds it); None for any other sample or unit."""
        if channel == keys.JOINTS and unit in self.arms.layout.arms:
            if len(payload.angles_deg) != 7:
                return None
            return self.arms.transforms(unit, payload.angles_deg, payload.stamp_ns)
        if channel == G1_LOWSTATE and unit in self.g1s.devices:
            return self.g1s.transforms(unit, payload)
        return None


class RecordingExtras:
    """What ``fleet record`` writes next to the key-space channels so that Foxglove shows the
    arms and G1s in 3D: each unit's URDF (as a message at the start, and the package's URDFs
    as the attachments ``d1_550.urdf`` and ``g1_29dof.urdf``) and a ``foxglove.FrameTransforms``
    per joints sample or G1 lowstate."""

    def __init__(self, frames: FleetFrames) -> None:
        self.frames = frames
        schema = FrameTransforms.get_schema()
        self._tf_schema = (schema.name, schema.encoding, bytes(schema.data))

    def attachments(self) -> list[tuple[str, bytes, str]]:
        """The URDFs as they are in the package (the G1's only with a G1 in the layout)."""
        out = [("d1_550.urdf", self.frames.arms.urdf_text.encode(), "application/xml")]
        if self.frames.g1s.devices:
            out.append(
                ("g1_29dof.urdf", self.frames.g1s.body.urdf_text.encode(), "application/xml")
            )
        return out

    def initial(self) -> list[DerivedMessage]:
        """Each unit's prefixed URDF."""
        schema = json.dumps(URDF_SCHEMA).encode()
        return [
            DerivedMessage(
                urdf_topic(unit),
                "std_msgs/String",
                "jsonschema",
                schema,
                "json",
                self.frames.urdf_message(unit),
            )
            for unit in self.frames.units
        ]

    def derive(self, unit: str | None, channel: str, payload: Any) -> list[DerivedMessage]:
        """The transforms of a joints sample of a laid-out arm or a lowstate of a laid-out G1."""
        if unit is None:
            return []
        message = self.frames.transforms_of(unit, channel, payload)
        if message is None:
            return []
        name, encoding, data = self._tf_schema
        return [
            DerivedMessage(
                transforms_topic(unit), name, encoding, data, "protobuf", bytes(message.encode())
            )
        ]
