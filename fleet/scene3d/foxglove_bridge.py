"""``fleet foxglove``: the live fleet for Foxglove, with Foxglove's own SDK (``foxglove-sdk``).

A WebSocket server (127.0.0.1:8765 by default; subprotocol ``foxglove.sdk.v1``), behind the
viewer's protections (issue 28): a per-run token and an Origin allow-list checked by
``fleet/scene3d/foxglove_gate.py`` in front of the SDK's server, which listens on a private loopback
port with TLS only the gate trusts. Under ``[security]`` the bridge runs as an observer (what
it serves is what an observer may read). It publishes:
- per arm and per G1, ``/d1/<id>/robot_description`` (the URDF, re-sent every second so a
  late client gets it) and ``/d1/<id>/transforms`` (``foxglove.FrameTransforms`` from our
  forward kinematics, under the arm's base pose or the G1's standing pelvis: frames3d.py), one
  per joints sample of an arm, one per lowstate of a G1 (stamped with the sample's own stamp);
- the key-space channels themselves, one channel per Zenoh key, JSON with the payload's JSON
  Schema (as ``fleet record`` writes them): joints, status, contact, diag, stop requests
  (``estop``), acks, reports, resets and the fleet state; each device's state (a G1's FSM and
  its stop latch, as an arm's status carries its stop) and a G1's lowstate.

Key-space channels live in a ``PinnedTable`` (fleet/tables.py): every channel of the
inventory's arms and devices and of the fleet itself is always advertised; made-up names share
``MAX_KEY_CHANNELS`` and the least recently used is unadvertised for a newer one.

Threads: the Zenoh callback only appends to a bounded deque (overflow counted in ``dropped``);
the ``foxglove`` thread decodes (through the channel table), logs to the SDK and computes the
transforms; the gate has its own (foxglove_gate.py). Shutdown: undeclare -> stop the thread ->
close the gate -> stop the server -> close the session.
"""

from __future__ import annotations

import collections
import logging
import threading
import time

import foxglove
import zenoh
from foxglove.channels import FrameTransformsChannel

from fleet.devices import kind_of as device_kind_of
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.record.layout import layout_of
from fleet.record.writer import channel_schema
from fleet.scene3d.foxglove_gate import FOXGLOVE_APP_ORIGIN, LOOPBACK, FoxgloveGate, PrivateTls
from fleet.scene3d.frames3d import URDF_SCHEMA, FleetFrames, transforms_topic, urdf_topic
from fleet.security.session import open_session
from fleet.tables import PinnedTable
from fleet.tap import kind_of
from fleet.web.access import AccessPolicy, new_token, url_host
from fleet.wire import keys, payloads
from fleet.wire.session import close_bounded

log = logging.getLogger("fleet.foxglove")

DEFAULT_PORT = 8765
INBOX_DEPTH = 10_000
MAX_KEY_CHANNELS = 1000
"""At most this many channels of keys outside the inventory (made-up names) are advertised; the
inventory's own are always (fleet/tables.py)."""
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
        keys.RESET_ACK,
        keys.STOP_REPORT,
        keys.STATE,
        keys.COORDINATOR_DIAG,
        # Every device kind's state, contacts, stops, acks and diag: rows of the
        # channel table (resets and commands stay off, as for arms' commands).
        *(
            f"{kind}/{channel}"
            for kind in keys.DEVICE_KINDS
            for channel in (
                keys.STATE,
                keys.CONTACT,
                keys.LOWSTATE,
                keys.DIAG,
                keys.ESTOP,
                keys.ESTOP_ACK,
                keys.RESET_ACK,
            )
            if f"{kind}/{channel}" in payloads.CHANNELS
        ),
    }
)


class BridgeRefused(ValueError):
    """The bridge cannot serve as asked (the message says why and what to do)."""


class FoxgloveBridge:
    """The fleet of ``inventory`` on a Foxglove WebSocket server behind the gate. A context
    manager. ``token``: None makes a random one (``url`` carries it); ``allow_origins``: pages
    of these origins may connect too (with the token)."""

    def __init__(
        self,
        inventory: Inventory,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        token: str | None = None,
        allow_origins: tuple[str, ...] = (),
    ):
        check_observer(inventory)
        self.inventory = inventory
        self.host = host
        self.keys = keys.KeySpace(inventory.fleet)
        self.frames = FleetFrames.load(layout_of(inventory))
        self.dropped = 0
        self.bad = 0
        self.published = 0
        self.guard = ThreadGuard("foxglove")
        self.failed = self.guard.failed
        self._inbox: collections.deque[tuple[str, bytes, int]] = collections.deque()
        self._stop = threading.Event()
        self._closed = False
        self.context = foxglove.Context()
        tls = PrivateTls.make()
        self.server = foxglove.start_server(
            name=f"d1-fleet {inventory.fleet}",
            host=LOOPBACK,
            port=0,
            context=self.context,
            tls_cert=tls.cert_pem,
            tls_key=tls.key_pem,
        )
        policy = AccessPolicy(
            token or new_token(),
            host,
            (FOXGLOVE_APP_ORIGIN, *allow_origins),
            allow_no_origin=True,
        )
        try:
            self.gate = FoxgloveGate(policy, host, port, self.server.port, tls, self.guard)
        except BaseException:
            self.server.stop()
            raise
        self.port = self.gate.port
        ctx = self.context
        units = self.frames.units  # the arms and the G1s
        self._tf = {u: FrameTransformsChannel(transforms_topic(u), context=ctx) for u in units}
        self._urdf = {
            u: foxglove.Channel(urdf_topic(u), schema=URDF_SCHEMA, context=ctx) for u in units
        }
        self._channels: PinnedTable[str, foxglove.Channel] = PinnedTable(
            MAX_KEY_CHANNELS, self._is_inventory_key, lambda _key, channel: channel.close()
        )
        try:
            self.session = open_session(inventory)
        except BaseException:
            self.gate.close()
            self.server.stop()
            raise
        self._subscriber = self.session.declare_subscriber(self.keys.everything, self._on_sample)
        self._thread = self.guard.thread(self._run, "foxglove")
        self._thread.start()

    @property
    def url(self) -> str:
        """What to open in Foxglove: the public address with this run's token."""
        return self.gate.url(url_host(self.host))

    def _is_inventory_key(self, key: str) -> bool:
        """A key of the fleet itself or of one of the inventory's arms or devices."""
        try:
            parsed = self.keys.parse_key(key)
        except keys.KeyError_:
            return False
        if parsed.kind == keys.FLEET_LEVEL:
            return not parsed.unit and not parsed.principal
        if parsed.kind == keys.ARM:
            return parsed.unit in self.inventory.arms
        device = self.inventory.devices.get(parsed.unit)
        return device is not None and device_kind_of(device).key == parsed.kind

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: hand off, never block. A datagram copy (``keys.DATAGRAM``) repeats
        what its key carries: not a channel of its own."""
        if keys.is_datagram_key(str(sample.key_expr)):
            return
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
        for unit, channel in self._urdf.items():
            channel.log(self.frames.urdf_message(unit), log_time=stamp_ns)

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
        channel.log(data, log_time=stamp_ns)
        self.published += 1
        unit = self.keys.parse_key(key).unit
        if unit in self._tf:  # an arm's joints or a G1's lowstate pose it (the same code records)
            transforms = self.frames.transforms_of(unit, kind, payload)
            if transforms is not None:
                self._tf[unit].log(transforms, log_time=stamp_ns)

    def _channel(self, key: str, kind: str) -> foxglove.Channel:
        def make(key: str) -> foxglove.Channel:
            name, schema = channel_schema(kind)
            return foxglove.Channel(key, schema={**schema, "title": name}, context=self.context)

        return self._channels.get(key, make)

    def close(self) -> None:
        """Undeclare -> stop the thread -> stop the server -> close the session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._subscriber.undeclare()
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.gate.close()
        self.server.stop()
        close_bounded(self.session, "session")

    def __enter__(self) -> FoxgloveBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def check_observer(inventory: Inventory) -> None:
    """Under ``[security]``, the bridge serves only what an observer may read: it acts as one
    (the default principal ``viewer``). BridgeRefused otherwise."""
    role = inventory.role_of(inventory.principal)
    if inventory.security.enabled and role != "observer":
        raise BridgeRefused(
            f"under [security] fleet foxglove acts as an observer, and principal "
            f"{inventory.principal!r} has role {role!r}; "
            "leave --principal out (default 'viewer') or name an observer"
        )
