"""The agent's device host: serves the devices beside the arms (``fleet/devices``: Dex1-1
grippers, G1s) of one DDS network, each through its kind's relay (``DeviceKind.agent``).

The D1 path (``link``, ``relay``, ``serving``...) is untouched: devices run in their own agent
process (``edge-agent --device ID``), with their own DDS participant and Zenoh session.

Threads, all under one ``ThreadGuard`` (a failure stops and latches every device, then the
process exits 1):
- ``dev-relay``: a DDS WaitSet over the device readers that want waking (``ReadySet``); ready
  readers go to their relay's ``on_data``, then its ``tick``; each relay's ``tick`` also runs
  when the time it asked for comes (a gripper polls its 500 Hz state there, at its relay rate:
  waking for every sample cost more than the work), at least every ``TICK_MAX_S``;
- ``dev-commands``: commands from a bounded queue (full: 4003 "busy" at once, from the
  callback); a G1 RPC may block it up to its timeout, never the stops;
- ``dev-safety``: stops and resets from a bounded FIFO (a stop that finds it full still
  latches every device: its payload is not needed to stop).
Zenoh callbacks only decode (size-capped) and hand off. Shutdown order: tokens and queryables
first (nobody can command any more), then the loops stop and are joined, then DDS and Zenoh
close.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any

import zenoh

from edge_agent.link import ReadySet
from fleet.d1 import dds
from fleet.devices import kind_of
from fleet.devices.base import DeviceReply
from fleet.devices.relay import DeviceRelay, error_reply
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.security.session import open_session
from fleet.wire import keys, payloads
from fleet.wire import messages as m

log = logging.getLogger("edge_agent.devices")

TICK_MAX_S = 0.1
"""The relay thread's longest wait: every relay ticks at least this often (it asks for more)."""
IDLE_WAIT_S = 1.0
"""The command and safety loops' longest wait (close wakes them at once): a device agent that
serves a 500 Hz gripper should not spend its budget waking up to find nothing."""
COMMAND_DEPTH = 64
SAFETY_DEPTH = 256
JSON = zenoh.Encoding.APPLICATION_JSON


@dataclass(frozen=True)
class _Command:
    relay: DeviceRelay
    payload: bytes
    principal: str
    query: zenoh.Query
    key: str


class DeviceHost:
    """Serve ``device_ids`` of ``inventory``. A context manager; ``start`` runs it."""

    def __init__(self, inventory: Inventory, device_ids: list[str]) -> None:
        self.keys = keys.KeySpace(inventory.fleet)
        self.guard = ThreadGuard("edge-agent devices", on_failure=self._on_failure)
        self.failed = self.guard.failed
        self._stopping = threading.Event()
        self._channel = dds.DdsChannel(*inventory.device_network(device_ids))
        self.session = open_session(inventory)
        self._publishers: dict[tuple[str, str], zenoh.Publisher] = {}
        self.relays: dict[str, DeviceRelay] = {}
        self._kind_of: dict[str, str] = {}
        readers: list[Any] = []
        self._reader_map: list[tuple[DeviceRelay, int]] = []
        for device_id in device_ids:
            config = inventory.device(device_id)
            kind = kind_of(config)
            self._kind_of[device_id] = kind.key
            self._declare_publishers(kind.key, device_id)
            relay = kind.load("agent")(config, self._channel.participant, self._put(device_id))
            self.relays[device_id] = relay
            for index, reader in enumerate(relay.readers):
                readers.append(reader)
                self._reader_map.append((relay, index))
        self._ready = ReadySet(self._channel.participant, readers)
        self._commands: queue.Queue[_Command | None] = queue.Queue(maxsize=COMMAND_DEPTH)
        self._safety: queue.Queue[tuple[str, str | None, m.StopRequest | None] | None] = (
            queue.Queue(maxsize=SAFETY_DEPTH)
        )
        self.bad_payloads = 0
        self._zenoh: list[Any] = []
        self._threads = [
            self.guard.thread(self._relay_loop, "dev-relay"),
            self.guard.thread(self._command_loop, "dev-commands"),
            self.guard.thread(self._safety_loop, "dev-safety"),
        ]

    # ------------------------------------------------------------------ Zenoh side

    def _declare_publishers(self, kind: str, device: str) -> None:
        drop, block = zenoh.CongestionControl.DROP, zenoh.CongestionControl.BLOCK
        for channel, congestion, priority in (
            (keys.STATE, drop, zenoh.Priority.DATA_HIGH),
            (keys.CONTACT, block, zenoh.Priority.DATA_HIGH),
            (keys.ESTOP_ACK, block, zenoh.Priority.REAL_TIME),
            (keys.DIAG, drop, zenoh.Priority.DATA),
        ):
            self._publishers[(device, channel)] = self.session.declare_publisher(
                self.keys.device(kind, device, channel),
                encoding=JSON,
                congestion_control=congestion,
                priority=priority,
            )

    def _put(self, device: str):  # type: ignore[no-untyped-def]
        def put(channel: str, payload: bytes, _reliable: bool) -> None:
            self._publishers[(device, channel)].put(payload)

        return put

    def start(self) -> DeviceHost:
        """Start the threads, then serve the key space (tokens last: announced once served)."""
        for thread in self._threads:
            thread.start()
        wrap, sub = self.guard.wrap, self.session.declare_subscriber
        self._zenoh.append(sub(self.keys.estop, wrap(self._on_stop(None), "estop")))
        self._zenoh.append(sub(self.keys.reset, wrap(self._on_reset(None), "reset")))
        self._zenoh.append(sub(self.keys.heartbeat, wrap(self._on_heartbeat, "heartbeat")))
        for device, kind in self._kind_of.items():
            key = self.keys.device
            self._zenoh.append(sub(key(kind, device, keys.ESTOP), wrap(self._on_stop(device), "s")))
            self._zenoh.append(
                sub(key(kind, device, keys.RESET), wrap(self._on_reset(device), "r"))
            )
            self._zenoh.append(
                self.session.declare_queryable(
                    f"{key(kind, device, keys.CMD)}/*", wrap(self._on_query(device), "cmd")
                )
            )
        for device, kind in self._kind_of.items():
            token = self.session.liveliness().declare_token(
                self.keys.device(kind, device, keys.AGENT)
            )
            self._zenoh.append(token)
        return self

    def _queue_safety(self, item: tuple[str, str | None, m.StopRequest | None]) -> None:
        try:
            self._safety.put_nowait(item)
        except queue.Full:
            # A stop is never lost: latch every device with a local request instead.
            if item[0] in ("stop", "beat"):
                self._latch_all("safety queue full (flood)")

    def _on_stop(self, device: str | None):  # type: ignore[no-untyped-def]
        def handler(sample: zenoh.Sample) -> None:
            try:
                request = payloads.STOP.decode(sample.payload.to_bytes())
            except payloads.PayloadError:
                self.bad_payloads += 1
                request = None  # an undecodable stop still stops
            self._queue_safety(("stop", device, request))

        return handler

    def _on_reset(self, device: str | None):  # type: ignore[no-untyped-def]
        def handler(sample: zenoh.Sample) -> None:
            try:
                payloads.RESET.decode(sample.payload.to_bytes())
            except payloads.PayloadError:
                self.bad_payloads += 1
                return
            self._queue_safety(("reset", device, None))

        return handler

    def _on_heartbeat(self, sample: zenoh.Sample) -> None:
        try:
            beat = payloads.HEARTBEAT.decode(sample.payload.to_bytes())
        except payloads.PayloadError:
            self.bad_payloads += 1
            return
        request = beat.stops.get("*")
        if request is not None:
            self._queue_safety(("beat", None, request))
        for device in self.relays:
            if device in beat.stops:
                self._queue_safety(("beat", device, beat.stops[device]))

    def _on_query(self, device: str):  # type: ignore[no-untyped-def]
        relay = self.relays[device]
        key = f"{self.keys.device(self._kind_of[device], device, keys.CMD)}"

        def handler(query: zenoh.Query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            principal = str(query.key_expr).rpartition("/")[2]
            reply_key = f"{key}/{principal}"
            try:
                self._commands.put_nowait(_Command(relay, payload, principal, query, reply_key))
            except queue.Full:
                busy = error_reply(device, m.ErrorCode.BUSY, "busy: too many commands queued")
                query.reply(reply_key, m.encode(busy), encoding=JSON)
                query.drop()

        return handler

    # ------------------------------------------------------------------ threads

    def _relay_loop(self) -> None:
        now = time.monotonic()
        due = {device: now for device in self.relays}
        while not self._stopping.is_set():
            wake = min(due.values(), default=now + TICK_MAX_S)
            ready = self._ready.wait(max(0.0, min(wake, now + TICK_MAX_S) - time.monotonic()))
            now = time.monotonic()
            ticked: set[str] = set()
            for index in ready:
                relay, local = self._reader_map[index]
                relay.on_data(local, now)
                ticked.add(relay.device)
            for device, relay in self.relays.items():
                if device in ticked or now >= due[device]:
                    due[device] = relay.tick(now)

    def _command_loop(self) -> None:
        while not self._stopping.is_set():
            try:
                item = self._commands.get(timeout=IDLE_WAIT_S)
            except queue.Empty:
                continue
            if item is None:  # close's wake-up
                continue
            reply: DeviceReply = item.relay.command(item.payload, item.principal)
            item.query.reply(item.key, m.encode(reply), encoding=JSON)
            item.query.drop()

    def _safety_loop(self) -> None:
        while not self._stopping.is_set():
            try:
                item = self._safety.get(timeout=IDLE_WAIT_S)
            except queue.Empty:
                continue
            if item is None:  # close's wake-up
                continue
            what, device, request = item
            targets = [self.relays[device]] if device is not None else list(self.relays.values())
            for relay in targets:
                if what == "reset":
                    relay.reset()
                    log.info("%s: reset", relay.device)
                else:  # a heartbeat's repeat of a latched stop is not acknowledged again
                    request = request or _local_stop("undecodable stop payload")
                    relay.stop(request, repeat_ack=what == "stop")

    def _latch_all(self, why: str) -> None:
        for relay in self.relays.values():
            relay.stop(_local_stop(why))

    def _on_failure(self, why: str) -> None:
        self._latch_all(f"agent thread failed ({why})")

    # ------------------------------------------------------------------ shutdown

    def close(self) -> None:
        """Tokens and queryables, then the loops, then DDS and Zenoh (idempotent)."""
        for entity in reversed(self._zenoh):
            entity.undeclare()
        self._zenoh.clear()
        self._stopping.set()
        self._ready.wake()
        for waiting in (self._commands, self._safety):
            # Wake the loop now (a full queue: it is busy and sees _stopping next).
            with contextlib.suppress(queue.Full):
                waiting.put_nowait(None)
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=2.0)
        for publisher in self._publishers.values():
            publisher.undeclare()
        self._publishers.clear()
        if self._channel is not None:
            self._channel.close()
            self._channel = None  # type: ignore[assignment]
        self.session.close()

    def __enter__(self) -> DeviceHost:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _local_stop(why: str) -> m.StopRequest:
    return m.StopRequest(
        stamp_ns=time.time_ns(), source="edge-agent", stop_id=f"local-{time.time_ns()}", reason=why
    )
