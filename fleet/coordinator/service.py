"""The coordinator process: fleet state, heartbeat, stop bookkeeping, multi-arm commands.

Threads: ``heartbeat`` (heartbeat at the inventory's rate, fleet state every other beat),
``events`` (liveliness, stops, resets, stop acks), ``multi-arm`` (coordinator/cmd queries).
Zenoh callbacks only record a time or queue the sample. A stop never depends on this process:
agents subscribe to the stop keys themselves; the coordinator repeats latched stops in its
heartbeat (for agents that missed one) and reports the fan-out.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import queue
import socket
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor

import msgspec
import zenoh

from fleet.client import STOP_QOS, FleetClient
from fleet.coordinator.contact_actions import perform
from fleet.coordinator.contact_policy import Action, ContactPolicy
from fleet.coordinator.state import FleetStateTracker
from fleet.coordinator.stops import FLEET, StopBook
from fleet.inventory import Inventory, InventoryError
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, ErrorInfo, encode
from fleet.wire.session import open_client

log = logging.getLogger("fleet.coordinator")
JSON = zenoh.Encoding.APPLICATION_JSON


@dataclasses.dataclass(frozen=True)
class _Event:
    channel: str
    arm: str | None
    payload: bytes
    kind: zenoh.SampleKind


def _log_failure(future: Future[None]) -> None:
    """A pool task's exception is logged, never lost."""
    if not future.cancelled() and future.exception() is not None:
        log.error("a multi-arm request failed", exc_info=future.exception())


class Coordinator:
    """One fleet's coordinator. A context manager; ``start()`` then ``close()``."""

    def __init__(self, inventory: Inventory) -> None:
        self.inventory = inventory
        self.id = f"coordinator@{socket.gethostname()}:{os.getpid()}"
        self.keys = keys.KeySpace(inventory.fleet)
        arms = list(inventory.arms)
        settings = inventory.coordinator
        self.period_s = 1.0 / settings.heartbeat_hz
        self.state = FleetStateTracker(arms, settings.offline_after_s)
        self.stops = StopBook(arms)
        self.contacts = ContactPolicy()  # fleet contact table, policies, collision memory
        self._contact_actions: list[Action] = []  # guarded by self.lock, done off-thread
        self.lock = threading.Lock()  # guards self.state and self.stops
        self.stopping = threading.Event()
        self._events: queue.SimpleQueue[_Event] = queue.SimpleQueue()
        self._queries: queue.Queue[zenoh.Query] = queue.Queue(maxsize=64)
        self.session = open_client(inventory.endpoints)
        self.client = FleetClient(inventory, self.session)
        self._declared: list[zenoh.Subscriber[None] | zenoh.Queryable[None]] = []
        self._declare()
        self._heartbeat_pub = self.session.declare_publisher(
            self.keys.heartbeat, encoding=JSON, **STOP_QOS
        )
        self._state_pub = self.session.declare_publisher(self.keys.state, encoding=JSON)
        self._report_pub = self.session.declare_publisher(self.keys.stop_report, encoding=JSON)
        self._pool = ThreadPoolExecutor(max_workers=16, thread_name_prefix="fan-out")
        # Multi-arm requests are served side by side: one that waits for its arms to reach
        # their targets must not hold up the next. A pool of its own: a request fans out on
        # _pool, and sharing one pool could starve it of workers.
        self._requests = ThreadPoolExecutor(max_workers=4, thread_name_prefix="multi-arm")
        self._threads = [
            threading.Thread(target=self._loop(self._beat), name="heartbeat", daemon=True),
            threading.Thread(target=self._loop(self._drain_events), name="events", daemon=True),
            threading.Thread(target=self._loop(self._serve_query), name="multi-arm", daemon=True),
        ]

    def _declare(self) -> None:
        sub = self.session.declare_subscriber
        self._declared += [
            self.session.liveliness().declare_subscriber(
                self.keys.all_arms(keys.AGENT), self._on_token, history=True
            ),
            sub(self.keys.all_arms(keys.STATUS), self._on_status),
            sub(self.keys.estop, self._queue(keys.ESTOP)),
            sub(self.keys.all_arms(keys.ESTOP), self._queue(keys.ESTOP)),
            sub(self.keys.reset, self._queue(keys.RESET)),
            sub(self.keys.all_arms(keys.RESET), self._queue(keys.RESET)),
            sub(self.keys.all_arms(keys.ESTOP_ACK), self._queue(keys.ESTOP_ACK)),
            sub(self.keys.all_arms(keys.CONTACT), self._queue(keys.CONTACT)),
            self.session.declare_queryable(self.keys.coordinator_cmd, self._on_query),
        ]

    # ------------------------------------------------------------------ Zenoh callbacks

    def _arm_of(self, sample: zenoh.Sample) -> str | None:
        key = str(sample.key_expr)
        try:
            return self.keys.parse_arm_key(key).arm
        except keys.KeyError_:
            return None

    def _on_token(self, sample: zenoh.Sample) -> None:
        self._events.put(_Event(keys.AGENT, self._arm_of(sample), b"", sample.kind))

    def _on_status(self, sample: zenoh.Sample) -> None:
        self._events.put(
            _Event(keys.STATUS, self._arm_of(sample), sample.payload.to_bytes(), sample.kind)
        )

    def _queue(self, channel: str):  # type: ignore[no-untyped-def]
        def handler(sample: zenoh.Sample) -> None:
            payload = sample.payload.to_bytes()
            self._events.put(_Event(channel, self._arm_of(sample), payload, sample.kind))

        return handler

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            self._queries.put_nowait(query)
        except queue.Full:
            log.warning("multi-arm command queue full: a query was not served")

    # ------------------------------------------------------------------ threads

    def _loop(self, step):  # type: ignore[no-untyped-def]
        def run() -> None:
            try:
                while not self.stopping.is_set():
                    step()
            except BaseException:
                log.exception("coordinator thread %s failed", threading.current_thread().name)
                raise

        return run

    def _beat(self) -> None:
        seq = 0
        next_beat = time.monotonic()
        while not self.stopping.is_set():
            now, stamp = time.monotonic(), time.time_ns()
            with self.lock:
                beat = m.Heartbeat(stamp, self.id, seq, self.period_s, self.stops.latched())
                state = self.state.state(self.id, now, stamp) if seq % 2 == 0 else None
            self._heartbeat_pub.put(encode(beat))
            if state is not None:
                self._state_pub.put(encode(state))
            seq += 1
            next_beat += self.period_s
            self.stopping.wait(max(0.0, next_beat - time.monotonic()))

    def _drain_events(self) -> None:
        try:
            event = self._events.get(timeout=0.2)
        except queue.Empty:
            return
        report: m.StopReport | None = None
        actions: list[Action] = []
        now = time.monotonic()
        try:
            with self.lock:
                report = self._apply(event, now)
                actions, self._contact_actions = self._contact_actions, []
        except msgspec.DecodeError as exc:
            log.warning("ignored a malformed %s sample: %s", event.channel, exc)
        if report is not None:
            self._report_pub.put(encode(report))
        for action in actions:  # contact policy: commands and stops, on the pool's threads
            self._pool.submit(perform, self.client, self.id, action)

    def _apply(self, event: _Event, now: float) -> m.StopReport | None:
        """Apply one event (caller holds the lock)."""
        if event.channel == keys.AGENT and event.arm is not None:
            self.state.on_token(event.arm, event.kind == zenoh.SampleKind.PUT, now)
        elif event.channel == keys.STATUS and event.arm is not None:
            self.state.on_status(event.arm, payloads.STATUS.decode(event.payload), now)
        elif event.channel == keys.ESTOP:
            request = payloads.STOP.decode(event.payload)
            self.stops.on_stop(event.arm or FLEET, request)
            log.warning(
                "stop %s by %s on %s", request.stop_id[:8], request.source, event.arm or "all"
            )
        elif event.channel == keys.RESET:
            self.stops.on_reset(event.arm or FLEET)
        elif event.channel == keys.CONTACT and event.arm is not None:
            contact = payloads.CONTACT.decode(event.payload)
            self._contact_actions += self.contacts.on_event(event.arm, contact, now)
            self.state.on_contact(event.arm, self.contacts.in_contact(event.arm))
        elif event.channel == keys.ESTOP_ACK:
            return self.stops.on_ack(payloads.STOP_ACK.decode(event.payload))
        return None

    # ------------------------------------------------------------------ multi-arm commands

    def _serve_query(self) -> None:
        try:
            query = self._queries.get(timeout=0.2)
        except queue.Empty:
            return
        self._requests.submit(self._answer, query).add_done_callback(_log_failure)

    def _answer(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            reply = self.command(payloads.MULTI_REQUEST.decode(payload))
        except msgspec.DecodeError as exc:
            reply = m.MultiArmReply(False, {}, None, ErrorInfo(int(ErrorCode.PARAMETER), str(exc)))
        except InventoryError as exc:
            reply = m.MultiArmReply(False, {}, None, ErrorInfo(int(ErrorCode.PARAMETER), str(exc)))
        query.reply(query.key_expr, encode(reply), encoding=JSON)
        query.drop()

    def command(self, request: m.MultiArmRequest) -> m.MultiArmReply:
        """Send one command to every arm of ``request.target`` as this coordinator (the owner);
        with sync, all arms get the same start time. Raises InventoryError for a bad target."""
        arms = self.inventory.resolve(request.target)
        refused = self._avoided(arms, request)
        if refused is not None:
            return refused
        changes: dict[str, object] = {"owner": self.id}
        if request.sync and len(arms) > 1:
            lead = (
                request.lead_s
                if request.lead_s is not None
                else self.inventory.coordinator.sync_lead_s
            )
            changes["start_at_ns"] = time.time_ns() + int(lead * 1e9)
        command = msgspec.structs.replace(request.command, **changes)
        replies = dict(zip(arms, self._pool.map(lambda a: self.client.command(a, command), arms)))
        written = [r.written_ns for r in replies.values() if r.ok and r.written_ns is not None]
        skew = round((max(written) - min(written)) / 1e6, 3) if len(written) > 1 else None
        return m.MultiArmReply(all(r.ok for r in replies.values()), replies, skew)

    def _avoided(self, arms: list[str], request: m.MultiArmRequest) -> m.MultiArmReply | None:
        """Declare the request's phase; refuse a target past a place the collision memory
        avoids (repeated contacts there)."""
        now, command = time.monotonic(), request.command
        targets: dict[int, float] = {}
        if isinstance(command, m.MoveJoint):
            targets = {command.joint: command.angle_deg}
        elif isinstance(command, m.MoveJoints):
            targets = dict(enumerate(command.angles_deg))
        with self.lock:
            for arm in arms:
                if request.phase is not None:
                    self.contacts.set_phase(arm, request.phase, now)
                for joint, target in targets.items():
                    place = self.contacts.memory.avoided(arm, joint, target, now)
                    if place is not None:
                        why = (
                            f"arm {arm!r} joint {joint}: target {target} deg goes past {place} "
                            "deg, where it met an obstacle repeatedly (collision memory; it "
                            "expires, or clear it after a workspace change)"
                        )
                        return m.MultiArmReply(
                            False, {}, None, ErrorInfo(int(ErrorCode.REJECTED), why)
                        )
        return None

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> Coordinator:
        """Start the threads."""
        for thread in self._threads:
            thread.start()
        log.info("coordinator %s serving fleet %r", self.id, self.inventory.fleet)
        return self

    def close(self) -> None:
        """Stop the loops, join, undeclare, close the session (idempotent). Agents holding
        arms under this coordinator's command will hold them when the heartbeat stops."""
        if self.stopping.is_set():
            return
        self.stopping.set()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=2.0)
        self._requests.shutdown(wait=False, cancel_futures=True)
        self._pool.shutdown(wait=False, cancel_futures=True)
        for entity in self._declared:
            entity.undeclare()
        for publisher in (self._heartbeat_pub, self._state_pub, self._report_pub):
            publisher.undeclare()
        self.session.close()

    def __enter__(self) -> Coordinator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
