"""Arms in 3D for Foxglove: per arm, its URDF (link names prefixed ``<arm>/``) and the link
transforms of a joints sample as Foxglove's well-known ``foxglove.FrameTransforms``.

Frames: ``world`` -> ``<arm>/<root link>`` is the arm's base pose (inventory or recorded
layout); then every URDF joint is one transform ``<arm>/<parent link>`` -> ``<arm>/<child link>``
computed by our forward kinematics (kinematics.py, which the viewer draws with too).
Foxglove's 3D panel places the URDF (loaded from the ``/d1/<arm>/robot_description`` topic,
``{"data": urdf}``, as ROS's ``std_msgs/String`` would carry it) on those frames.

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

from fleet.record.layout import ArmPlacement, FleetLayout
from fleet.record.writer import DerivedMessage
from fleet.scene3d import kinematics as k
from fleet.wire import keys

WORLD_FRAME = "world"
TOPIC_PREFIX = "/d1"
"""The 3D topics start with ``/d1/``: no Zenoh key does, so ``fleet replay`` and the replay
viewer (which read channels by key) never mistake them for key-space channels."""
URDF_SCHEMA = {
    "title": "std_msgs/String",
    "description": "The arm's URDF (links prefixed with the arm's id) for Foxglove's 3D panel",
    "type": "object",
    "properties": {"data": {"type": "string"}},
}


def transforms_topic(arm: str) -> str:
    """The arm's FrameTransforms topic."""
    return f"{TOPIC_PREFIX}/{arm}/transforms"


def urdf_topic(arm: str) -> str:
    """The arm's URDF topic."""
    return f"{TOPIC_PREFIX}/{arm}/robot_description"


def prefixed_urdf(text: str, arm: str) -> str:
    """``text`` with every link name (and joint reference to one) prefixed ``<arm>/``, so the
    URDF's frames are the arm's own frames."""
    return re.sub(r'(<link\s+name|<parent\s+link|<child\s+link)="([^"]+)"', rf'\1="{arm}/\2"', text)


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
        return json.dumps({"data": prefixed_urdf(self.urdf_text, arm)}).encode()

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
        stamp = _timestamp(stamp_ns)
        links = self._forward(placement, angles_deg)
        base = k.base_transforms(placement.base_xyz, placement.base_rpy_deg)[0]
        names = [f"{arm}/{name}" for name in self.model.links]
        out = [_transform(WORLD_FRAME, names[0], base, stamp)]
        for i in range(1, len(names)):
            parent = self.model.parent[i]
            local = np.linalg.solve(links[parent], links[i])  # parent-from-child
            out.append(_transform(names[parent], names[i], local, stamp))
        return FrameTransforms(transforms=out)


class RecordingExtras:
    """What ``fleet record`` writes next to the key-space channels so that Foxglove shows the
    arms in 3D: each arm's URDF (as a message at the start and as the attachment
    ``d1_550.urdf``) and a ``foxglove.FrameTransforms`` per joints sample."""

    def __init__(self, frames: ArmFrames) -> None:
        self.frames = frames
        schema = FrameTransforms.get_schema()
        self._tf_schema = (schema.name, schema.encoding, bytes(schema.data))

    def attachments(self) -> list[tuple[str, bytes, str]]:
        """The URDF as it is in the package."""
        return [("d1_550.urdf", self.frames.urdf_text.encode(), "application/xml")]

    def initial(self) -> list[DerivedMessage]:
        """Each arm's prefixed URDF."""
        schema = json.dumps(URDF_SCHEMA).encode()
        return [
            DerivedMessage(
                urdf_topic(arm),
                "std_msgs/String",
                "jsonschema",
                schema,
                "json",
                self.frames.urdf_message(arm),
            )
            for arm in self.frames.layout.arms
        ]

    def derive(self, arm: str | None, channel: str, payload: Any) -> list[DerivedMessage]:
        """The transforms of a joints sample of a laid-out arm."""
        if arm is None or channel != keys.JOINTS or arm not in self.frames.layout.arms:
            return []
        if len(payload.angles_deg) != 7:
            return []
        message = self.frames.transforms(arm, payload.angles_deg, payload.stamp_ns)
        name, encoding, data = self._tf_schema
        return [
            DerivedMessage(
                transforms_topic(arm), name, encoding, data, "protobuf", bytes(message.encode())
            )
        ]
