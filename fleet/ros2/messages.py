"""The ROS messages ``fleet ros2`` publishes, as CDR bytes, and the Trigger service's CDR. Pure.

Field order and types are the ROS 2 interface definitions (common_interfaces, Jazzy):
``std_msgs/Header {builtin_interfaces/Time stamp {int32 sec, uint32 nanosec}, string frame_id}``;
``sensor_msgs/JointState {Header, string[] name, float64[] position, velocity, effort}``;
``std_msgs/String {string data}``; ``tf2_msgs/TFMessage {geometry_msgs/TransformStamped[]
{Header, string child_frame_id, Transform {Vector3 translation, Quaternion rotation (x y z w)}}}``;
``diagnostic_msgs/DiagnosticArray {Header, DiagnosticStatus[] {byte level, string name,
message, hardware_id, KeyValue[] values {string key, value}}}``; ``std_srvs/Trigger``: an empty
request (one placeholder octet on the wire), response ``{bool success, string message}``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from fleet.ros2.cdr import CdrError, CdrReader, CdrTemplate, CdrWriter

OK, WARN, ERROR, STALE = 0, 1, 2, 3
"""diagnostic_msgs/DiagnosticStatus levels."""


@dataclass(frozen=True)
class Transform:
    """One geometry_msgs/TransformStamped (stamp from the message it travels in)."""

    parent: str
    child: str
    xyz: tuple[float, float, float]
    xyzw: tuple[float, float, float, float]


@dataclass(frozen=True)
class Status:
    """One diagnostic_msgs/DiagnosticStatus."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...] = ()


def _header(w: CdrWriter, stamp_ns: int, frame_id: str) -> None:
    w.i32(stamp_ns // 1_000_000_000)
    w.u32(stamp_ns % 1_000_000_000)
    w.string(frame_id)


def joint_state(
    stamp_ns: int,
    names: Sequence[str],
    position: Sequence[float],
    velocity: Sequence[float] = (),
    effort: Sequence[float] = (),
    frame_id: str = "",
) -> bytes:
    """sensor_msgs/msg/JointState."""
    w = CdrWriter()
    _header(w, stamp_ns, frame_id)
    w.strings(list(names))
    w.f64s([float(v) for v in position])
    w.f64s([float(v) for v in velocity])
    w.f64s([float(v) for v in effort])
    return w.bytes()


def _stamp(stamp_ns: int) -> tuple[int, int]:
    return stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000


class JointStateTemplate:
    """sensor_msgs/msg/JointState of fixed ``names`` (and frame), written once: a sample packs
    its stamp and numbers (byte for byte ``joint_state``)."""

    def __init__(
        self, names: Sequence[str], frame_id: str = "", velocity: bool = False, effort: bool = False
    ) -> None:
        n = len(names)
        if n == 0:
            raise ValueError("a JointState template needs at least one joint")
        w = CdrWriter()
        w.slot("iI", (0, 0))
        w.string(frame_id)
        w.strings(list(names))
        for present in (True, velocity, effort):
            w.u32(n if present else 0)
            if present:
                w.slot(f"{n}d", [0.0] * n)
        self.names = tuple(names)
        self._template: CdrTemplate = w.template()

    def message(self, stamp_ns: int, *columns: Sequence[float]) -> bytes:
        """The CDR of one sample: ``position`` (then ``velocity``, ``effort`` when the template
        has them), each ``len(names)`` values."""
        return self._template.fill(_stamp(stamp_ns), *columns)


class TfTemplate:
    """tf2_msgs/msg/TFMessage of fixed (parent, child) frames, written once: a sample packs the
    stamp and each transform's translation and rotation (byte for byte ``tf_message``)."""

    def __init__(self, frames: Sequence[tuple[str, str]]) -> None:
        w = CdrWriter()
        w.u32(len(frames))
        for parent, child in frames:
            w.slot("iI", (0, 0))
            w.string(parent)
            w.string(child)
            w.slot("7d", [0.0] * 7)
        self.frames = tuple(frames)
        template = w.template()
        self._data = template.data
        self._stamps = [offset for offset, _packer in template.slots[0::2]]
        self._poses = [offset for offset, _packer in template.slots[1::2]]

    def message(self, stamp_ns: int, poses: Sequence[Sequence[float]]) -> bytes:
        """The CDR of one TFMessage: ``poses[i]`` is frame i's x y z, qx qy qz qw."""
        if len(poses) != len(self._poses):
            raise ValueError(f"{len(poses)} poses for {len(self._poses)} frames")
        buf = bytearray(self._data)
        sec, nsec = _stamp(stamp_ns)
        for offset in self._stamps:
            _STAMP.pack_into(buf, offset, sec, nsec)
        for offset, pose in zip(self._poses, poses, strict=True):
            _POSE.pack_into(buf, offset, *pose)
        return bytes(buf)


_STAMP = struct.Struct("<iI")
_POSE = struct.Struct("<7d")


def string(text: str) -> bytes:
    """std_msgs/msg/String."""
    w = CdrWriter()
    w.string(text)
    return w.bytes()


def tf_message(stamp_ns: int, transforms: Sequence[Transform]) -> bytes:
    """tf2_msgs/msg/TFMessage, every transform stamped ``stamp_ns``."""
    w = CdrWriter()
    w.u32(len(transforms))
    for t in transforms:
        _header(w, stamp_ns, t.parent)
        w.string(t.child)
        for v in (*t.xyz, *t.xyzw):
            w.f64(float(v))
    return w.bytes()


def diagnostic_array(stamp_ns: int, statuses: Sequence[Status]) -> bytes:
    """diagnostic_msgs/msg/DiagnosticArray."""
    w = CdrWriter()
    _header(w, stamp_ns, "")
    w.u32(len(statuses))
    for s in statuses:
        w.u8(s.level)
        w.string(s.name)
        w.string(s.message)
        w.string(s.hardware_id)
        w.u32(len(s.values))
        for key, value in s.values:
            w.string(key)
            w.string(value)
    return w.bytes()


def trigger_request_ok(data: bytes) -> bool:
    """True when ``data`` is the CDR of an (empty) std_srvs/srv/Trigger request: the header and
    the placeholder octet; anything else (no header, short, padding beyond 8 bytes) is False."""
    try:
        reader = CdrReader(data, max_len=64)
        reader.u8()
    except CdrError:
        return False
    return reader.left <= 3  # Fast-CDR may pad the message to a multiple of 4


def trigger_request() -> bytes:
    """The CDR of a Trigger request (what a ROS client sends)."""
    w = CdrWriter()
    w.u8(0)
    return w.bytes()


def trigger_response(success: bool, message: str) -> bytes:
    """std_srvs/srv/Trigger response."""
    w = CdrWriter()
    w.u8(1 if success else 0)
    w.string(message)
    return w.bytes()
