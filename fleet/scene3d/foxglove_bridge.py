"""``fleet foxglove``: the live fleet for Foxglove, with Foxglove's own SDK (``foxglove-sdk``).

A WebSocket server (127.0.0.1:8765 by default; subprotocol ``foxglove.sdk.v1``) publishes:
- per arm, ``/d1/<arm>/robot_description`` (the URDF, re-sent every second so a late client
  gets it) and ``/d1/<arm>/transforms`` (``foxglove.FrameTransforms`` from our forward
  kinematics, under the arm's base pose: frames3d.py), one per joints sample;
- the key-space channels themselves, one channel per Zenoh key, JSON with the payload's JSON
  Schema (as ``fleet record`` writes them): joints, status, contact, diag, stop requests
  (``estop``), acks, reports, resets and the fleet state.

Threads: the Zenoh callback only appends to a bounded deque (overflow counted in ``dropped``);
the ``foxglove`` thread decodes (through the channel table), logs to the SDK and computes the
transforms. Shutdown: undeclare -> stop the thread -> stop the server -> close the session.
"""

from __future__ import annotations

import collections
import logging
import threading
import time

import foxglove
import zenoh
from foxglove.channels import FrameTransformsChannel

from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.record.layout import layout_of
from fleet.record.writer import channel_schema
from fleet.scene3d.frames3d import URDF_SCHEMA, ArmFrames, transforms_topic, urdf_topic
from fleet.security.session import open_session
from fleet.tap import kind_of
from fleet.wire import keys, payloads

log = logging.getLogger("fleet.foxglove")

DEFAULT_PORT = 8765
INBOX_DEPTH = 10_000
MAX_KEY_CHANNELS = 1000
"""At most this many key-space channels are advertised (a flood of forged keys is dropped)."""
URDF_PERIOD_S = 1.0
BRIDGED = frozenset(
    {
        keys.JOINTS,
        keys.STATUS,
        keys.CONTACT,
        keys.DIAG,
        keys.ESTOP,
        keys.ESTOP_ACK,
        keys.RESET,
        keys.STOP_REPORT,
        keys.STATE,
        keys.COORDINATOR_DIAG,
        # Every device kind's state, contacts, stops, acks and diag (issue 21): rows of the
        # channel table (resets and commands stay off, as for arms' commands).
        *(
            f"{kind}/{channel}"
            for kind in keys.DEVICE_KINDS
            for channel in (keys.STATE, keys.CONTACT, keys.DIAG, keys.ESTOP, keys.ESTOP_ACK)
            if f"{kind}/{channel}" in payloads.CHANNELS
        ),
    }
)


class FoxgloveBridge:
    """The fleet of ``inventory`` on a Foxglove WebSocket server. A context manager."""

    def __init__(self, inventory: Inventory, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        self.inventory = inventory
        self.keys = keys.KeySpace(inventory.fleet)
        self.frames = ArmFrames.load(layout_of(inventory))
        self.dropped = 0
        self.bad = 0
        self.published = 0
        self.guard = ThreadGuard("foxglove")
        self.failed = self.guard.failed
        self._inbox: collections.deque[tuple[str, bytes, int]] = collections.deque()
        self._stop = threading.Event()
        self._closed = False
        self.context = foxglove.Context()
        self.server = foxglove.start_server(
            name=f"d1-fleet {inventory.fleet}", host=host, port=port, context=self.context
        )
        self.port = self.server.port
        ctx = self.context
        self._tf = {
            a: FrameTransformsChannel(transforms_topic(a), context=ctx) for a in inventory.arms
        }
        self._urdf = {
            a: foxglove.Channel(urdf_topic(a), schema=URDF_SCHEMA, context=ctx)
            for a in inventory.arms
        }
        self._channels: dict[str, foxglove.Channel] = {}
        try:
            self.session = open_session(inventory)
        except BaseException:
            self.server.stop()
            raise
        self._subscriber = self.session.declare_subscriber(self.keys.everything, self._on_sample)
        self._thread = self.guard.thread(self._run, "foxglove")
        self._thread.start()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: hand off, never block."""
        if len(self._inbox) < INBOX_DEPTH:
            self._inbox.append((str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))
        else:
            self.dropped += 1

    def _run(self) -> None:
        next_urdf = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_urdf:
                next_urdf = now + URDF_PERIOD_S
                self._publish_urdfs()
            if not self._inbox:
                self._stop.wait(0.01)
                continue
            for _ in range(min(len(self._inbox), 256)):
                self._bridge(*self._inbox.popleft())

    def _publish_urdfs(self) -> None:
        stamp_ns = time.time_ns()
        for arm, channel in self._urdf.items():
            channel.log(self.frames.urdf_message(arm), log_time=stamp_ns)

    def _bridge(self, key: str, data: bytes, stamp_ns: int) -> None:
        kind = kind_of(self.keys, key)
        if kind not in BRIDGED:
            return
        try:
            payload = payloads.decode(kind, data)
        except payloads.PayloadError:
            self.bad += 1
            return
        channel = self._channel(key, kind)
        if channel is None:
            return
        channel.log(data, log_time=stamp_ns)
        self.published += 1
        if kind == keys.JOINTS:
            arm = self.keys.parse_arm_key(key).arm
            if arm in self._tf and len(payload.angles_deg) == 7:
                self._tf[arm].log(
                    self.frames.transforms(arm, payload.angles_deg, payload.stamp_ns),
                    log_time=stamp_ns,
                )

    def _channel(self, key: str, kind: str) -> foxglove.Channel | None:
        channel = self._channels.get(key)
        if channel is None and len(self._channels) < MAX_KEY_CHANNELS:
            name, schema = channel_schema(kind)
            schema = {**schema, "title": name}
            channel = foxglove.Channel(key, schema=schema, context=self.context)
            self._channels[key] = channel
        return channel

    def close(self) -> None:
        """Undeclare -> stop the thread -> stop the server -> close the session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._subscriber.undeclare()
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.server.stop()
        self.session.close()

    def __enter__(self) -> FoxgloveBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
