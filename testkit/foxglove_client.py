"""A minimal client of the Foxglove WebSocket protocol (subprotocol ``foxglove.sdk.v1``), and
decoding of Foxglove's protobuf schemas with ``protobuf``: what a test needs to see what
Foxglove would see. Every wait is bounded."""

from __future__ import annotations

import base64
import json
import struct
import time
from typing import Any

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOL = "foxglove.sdk.v1"
OLD_SUBPROTOCOL = "foxglove.websocket.v1"
"""The same protocol under its first name: older Foxglove apps, Lichtblick, ws-protocol clients."""
MESSAGE_DATA = 0x01


def protobuf_class(schema_name: str, descriptor_set: bytes) -> Any:
    """The message class of ``schema_name`` from a serialized FileDescriptorSet."""
    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def _matrix(transform: Any) -> Any:
    """4x4 from a decoded foxglove.FrameTransform (protobuf)."""
    q, t = transform.rotation, transform.translation
    w, x, y, z = q.w, q.x, q.y, q.z
    out = np.eye(4)
    out[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    out[:3, 3] = [t.x, t.y, t.z]
    return out


def world_from_links(message: Any) -> dict[str, Any]:
    """Every child frame's world transform (4x4), composed from a decoded FrameTransforms'
    parent -> child transforms: what Foxglove's 3D panel places each link at."""
    edges = {t.child_frame_id: (t.parent_frame_id, _matrix(t)) for t in message.transforms}
    out: dict[str, Any] = {"world": np.eye(4)}

    def resolve(frame: str) -> Any:
        if frame not in out:
            parent, local = edges[frame]
            out[frame] = resolve(parent) @ local
        return out[frame]

    for frame in edges:
        resolve(frame)
    return out


def stamp_ns_of(message: Any) -> int:
    """The stamp of a decoded FrameTransforms (its first transform's), in ns."""
    stamp = message.transforms[0].timestamp
    return int(stamp.seconds) * 1_000_000_000 + int(stamp.nanos)


class FoxgloveClient:
    """One connection: the advertised channels, subscriptions, decoded messages."""

    def __init__(
        self,
        url: str,
        timeout_s: float = 10.0,
        origin: str | None = None,
        subprotocol: str = SUBPROTOCOL,
    ) -> None:
        self.ws: ClientConnection = connect(
            url,
            subprotocols=[subprotocol],  # type: ignore[list-item]
            open_timeout=timeout_s,
            origin=origin,  # type: ignore[arg-type]
        )
        assert self.ws.subprotocol == subprotocol
        self.server_info: dict[str, Any] | None = None
        self.channels: dict[int, dict[str, Any]] = {}
        self._subscriptions: dict[int, int] = {}  # subscription id -> channel id
        self._classes: dict[int, Any] = {}  # channel id -> its protobuf class (built once)

    def read(self, timeout_s: float) -> tuple[int, int, bytes] | None:
        """Handle text messages until a message-data frame (channel id, log time, payload)
        arrives, or None after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                frame = self.ws.recv(timeout=left)
            except TimeoutError:
                return None
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "serverInfo":
                    self.server_info = message
                elif message["op"] == "advertise":
                    self.channels.update({c["id"]: c for c in message["channels"]})
                elif message["op"] == "unadvertise":
                    for channel_id in message["channelIds"]:
                        self.channels.pop(channel_id, None)
                continue
            if frame[0] == MESSAGE_DATA:
                subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                return self._subscriptions[subscription], log_time, bytes(frame[13:])
        return None

    def topics(self) -> dict[str, dict[str, Any]]:
        """Advertised channels by topic."""
        return {c["topic"]: c for c in self.channels.values()}

    def wait_for_topics(self, wanted: set[str], timeout_s: float) -> dict[str, dict[str, Any]]:
        """Read until every topic in ``wanted`` is advertised; AssertionError otherwise."""
        deadline = time.monotonic() + timeout_s
        while not wanted <= set(self.topics()):
            assert time.monotonic() < deadline, f"not advertised: {wanted - set(self.topics())}"
            self.read(0.2)
        return self.topics()

    def subscribe(self, *topics: str) -> None:
        """Subscribe to advertised ``topics``."""
        subs = []
        for topic in topics:
            channel = self.topics()[topic]
            sub_id = len(self._subscriptions) + 1
            self._subscriptions[sub_id] = channel["id"]
            subs.append({"id": sub_id, "channelId": channel["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def decode(self, channel_id: int, payload: bytes) -> Any:
        """A message of a JSON or protobuf channel."""
        channel = self.channels[channel_id]
        if channel["encoding"] == "json":
            return json.loads(payload)
        assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
        cls = self._classes.get(channel_id)
        if cls is None:  # a descriptor pool per message took ms: a reader fell behind the stream
            cls = protobuf_class(channel["schemaName"], base64.b64decode(channel["schema"]))
            self._classes[channel_id] = cls
        return cls.FromString(payload)

    def close(self) -> None:
        """Close the connection."""
        self.ws.close()
