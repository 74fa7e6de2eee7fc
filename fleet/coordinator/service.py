"""The coordinator process: fleet state, heartbeat, stop bookkeeping, multi-arm commands.

Threads: ``heartbeat`` (heartbeat at the inventory's rate, fleet state every other beat, diag
once a second), ``events`` (tokens, stops and resets first, then statuses, stop acks and
contacts), ``multi-arm`` (coordinator/cmd queries, served on a bounded pool). All run under one
``ThreadGuard``: a failure stops the heartbeat at once and the process exits 1. Zenoh callbacks
only decode and queue (``intake.py``, bounded). A stop never depends on this process:
agents subscribe to the stop keys themselves; the coordinator repeats latched stops in its
heartbeat (for agents that missed one) and reports the fan-out.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import msgspec
import zenoh

from fleet.client import FleetClient, start_at_ns
from fleet.control import direct
from fleet.coordinator.contact_actions import perform
from fleet.coordinator.contact_policy import Action, ContactPolicy
from fleet.coordinator.desk import RequestDesk, error_reply
from fleet.coordinator.intake import Control, CoordinatorIntake
from fleet.coordinator.state import FleetStateTracker
from fleet.coordinator.stops import FLEET, StopBook
from fleet.devices import kind_of
from fleet.devices.unit import owner_of
from fleet.guard import ThreadGuard
from fleet.heartbeat import beat_until
from fleet.inventory import Inventory, InventoryError
from fleet.security.session import datagram_session, open_session
from fleet.security_config import COMMANDERS
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, encode
from fleet.wire.session import close_bounded
from fleet.wire.stoppath import TwoPathPublisher

log = logging.getLogger("fleet.coordinator")
JSON = zenoh.Encoding.APPLICATION_JSON


MAX_PENDING_ACTIONS = 64
"""Contact-policy actions waiting for a worker; more are dropped (counted): a flood of forged
contact events must not queue commands without bound."""
DIAG_PERIOD_S = 1.0
WATCHED_GRACE_S = 5.0
"""The beats keep their datagram copies this long after the last sign that a unit's watchdog
may watch this coordinator: a command it sent, or a unit's status or state naming it
(``watched_by``, reported 4-10 times a second over TCP, so late under loss)."""


class Coordinator:
    """One fleet's coordinator. A context manager; ``start()`` then ``close()``."""

    def __init__(self, inventory: Inventory) -> None:
        self.inventory = inventory
        self.id = f"coordinator@{socket.gethostname()[:64]}:{os.getpid()}"
        self.keys = keys.KeySpace(inventory.fleet)
        arms = list(inventory.arms)
        settings = inventory.coordinator
        self.period_s = 1.0 / settings.heartbeat_hz
        self.devices = {d: kind_of(c) for d, c in inventory.devices.items()}
        self.state = FleetStateTracker(
            arms, settings.offline_after_s, {d: k.key for d, k in self.devices.items()}
        )
        self.stops = StopBook(arms, devices=list(self.devices))
        self.contacts = ContactPolicy()  # fleet contact table, policies, collision memory
        self.lock = threading.Lock()  # guards self.state, self.stops and self.contacts
        self.stopping = threading.Event()
        self._closed = False
        # A failed thread stops the heartbeat at once (agents then hold the arms this
        # coordinator commands) and the process exits 1: no zombie that beats on.
        self.guard = ThreadGuard("coordinator", lambda _what: self.stopping.set())
        self.failed = self.guard.failed
        self.intake = CoordinatorIntake(self.keys, frozenset(arms))
        self.undecodable_stops = 0  # guarded by lock
        self.desk = RequestDesk(self.keys, self._serve, self.guard)
        self._pending_actions = 0  # guarded by lock
        self._next_diag = 0.0  # heartbeat thread only
        self._watch_source = owner_of(inventory.principal, self.id)
        """What an agent's watchdog names this coordinator (``watched_by``)."""
        self._watched_until = 0.0  # monotonic; a float written whole: no lock
        self.session = open_session(inventory)
        self.datagram = datagram_session(inventory, beside=self.session)
        self.datagram.open()  # the stops' datagram path (issue 24), before the first beat
        self.client = FleetClient(inventory, self.session, datagram=self.datagram)
        self._declared: list[zenoh.Subscriber[None] | zenoh.Queryable[None]] = []
        self._declare()
        # Both paths (issue 24): a beat held up by a TCP retransmission (>= 200 ms, doubling)
        # tripped agents' 0.5 s watchdogs under loss; its datagram copy is not held up.
        self._heartbeat_pub = TwoPathPublisher(
            self.session, self.datagram, self.keys.heartbeat_of(inventory.principal)
        )
        self._state_pub = self.session.declare_publisher(self.keys.state, encoding=JSON)
        self._report_pub = self.session.declare_publisher(self.keys.stop_report, encoding=JSON)
        self._diag_pub = self.session.declare_publisher(self.keys.coordinator_diag, encoding=JSON)
        self._pool = ThreadPoolExecutor(max_workers=16, thread_name_prefix="fan-out")
        # (the desk serves requests on a pool of its own: a request fans out on _pool, and
        # sharing one pool could starve it of workers)
        self._threads = [
            self.guard.thread(self._beat, "heartbeat"),
            self.guard.thread(self._drain_events, "events"),
            self.guard.thread(lambda: self.desk.run(self.stopping), "multi-arm"),
        ]

    def _declare(self) -> None:
        intake, wrap = self.intake, self.guard.wrap
        sub = self.session.declare_subscriber
        self._declared += [
            self.session.liveliness().declare_subscriber(
                self.keys.all_arms(keys.AGENT), wrap(intake.on_token, "token"), history=True
            ),
            sub(self.keys.all_arms(keys.STATUS), wrap(intake.on_status, "status")),
            # stops and resets on the receiving thread, in arrival order (fleet.control)
            sub(self.keys.estop, direct(wrap(intake.on_stop(True), "estop"))),
            sub(self.keys.all_arms(keys.ESTOP), direct(wrap(intake.on_stop(False), "estop"))),
            sub(self.keys.reset, direct(wrap(intake.on_reset(True), "reset"))),
            sub(self.keys.all_arms(keys.RESET), direct(wrap(intake.on_reset(False), "reset"))),
            sub(self.keys.all_arms(keys.ESTOP_ACK), wrap(intake.on_report, "estop-ack")),
            sub(self.keys.all_arms(keys.CONTACT), wrap(intake.on_report, "contact")),
            self.session.declare_queryable(
                self.keys.coordinator_cmd, wrap(self.desk.on_query, "coordinator-cmd")
            ),
        ]
        for kind in {k.key: k for k in self.devices.values()}.values():
            on_token, on_state, on_ack = intake.on_device(kind, frozenset(self.devices))
            key = self.keys.device
            self._declared += [
                self.session.liveliness().declare_subscriber(
                    key(kind.key, "*", keys.AGENT), wrap(on_token, "device-token"), history=True
                ),
                sub(key(kind.key, "*", keys.STATE), wrap(on_state, "device-state")),
                sub(key(kind.key, "*", keys.ESTOP_ACK), wrap(on_ack, "device-ack")),
            ]

    # ------------------------------------------------------------------ threads

    def _beat(self) -> None:
        beat_until(
            self.stopping,
            self._heartbeat_pub,
            self.id,
            self.period_s,
            self._latched,
            self._after,
            self._watched,
        )

    def _may_be_watched(self) -> None:
        """A sign that some unit's watchdog may watch this coordinator now."""
        self._watched_until = max(self._watched_until, time.monotonic() + WATCHED_GRACE_S)

    def _watched(self) -> bool:
        """Whether the beats' datagram copies go (``beat_until``): while a multi-arm request is
        served and ``WATCHED_GRACE_S`` after the last sign of a watch. An idle fleet's agents
        then get each beat once, over TCP (their stops keep both paths)."""
        return time.monotonic() < self._watched_until or self.desk.counters()[1] > 0

    def _latched(self) -> dict[str, m.StopRequest]:
        with self.lock:
            return self.stops.latched()

    def _after(self, seq: int, stamp_ns: int) -> None:
        """After a beat: the fleet state every other beat, the diag once a second."""
        if self.stopping.is_set():
            return  # a thread failed: publish nothing more
        now = time.monotonic()
        if seq % 2 == 0:
            with self.lock:
                state = self.state.state(self.id, now, stamp_ns)
            self._state_pub.put(encode(state))
        if now >= self._next_diag:
            self._next_diag = now + DIAG_PERIOD_S
            self._diag_pub.put(encode(self.diag(stamp_ns)))

    def diag(self, stamp_ns: int) -> m.CoordinatorDiag:
        """The coordinator's counters."""
        counters = self.intake.counters
        busy, active, bad_keys = self.desk.counters()
        return m.CoordinatorDiag(
            stamp_ns=stamp_ns,
            coordinator=self.id,
            bad_events=counters.bad_events,
            unknown_arms=counters.unknown_arms,
            undecodable_stops=self.undecodable_stops,
            dropped_events=counters.dropped_events,
            busy=busy,
            requests_active=active,
            bad_keys=bad_keys,
        )

    def _drain_events(self) -> None:
        while not self.stopping.is_set():
            self.intake.wake.wait(0.2)
            self.intake.wake.clear()
            control, statuses, reports = self.intake.take()
            stop_reports: list[m.StopReport] = []
            actions: list[Action] = []
            now = time.monotonic()
            with self.lock:
                for event in control:
                    self._apply_control(event, now)
                for arm, status in statuses.items():
                    self.state.on_status(arm, status, now)
                    if status.watched_by == self._watch_source:
                        self._may_be_watched()
                for device, (kind, state) in self.intake.take_device_states().items():
                    if getattr(state, "watched_by", None) == self._watch_source:
                        self._may_be_watched()
                    self.state.on_device_state(
                        device, state.link, state.estopped, kind.summary(state), now
                    )
                for report in reports:
                    if isinstance(report.payload, m.StopAck):
                        stop_report = self.stops.on_ack(report.arm, report.payload)
                        if stop_report is not None:
                            stop_reports.append(stop_report)
                    else:
                        actions += self.contacts.on_event(report.arm, report.payload, now)
                        self.state.on_contact(report.arm, self.contacts.in_contact(report.arm))
                actions = actions[: max(0, MAX_PENDING_ACTIONS - self._pending_actions)]
                self._pending_actions += len(actions)
            for stop_report in stop_reports:
                self._report_pub.put(encode(stop_report))
            for action in actions:  # contact policy: commands and stops, on the pool's threads
                self._pool.submit(self.guard.wrap(self._perform, "contact-action"), action)

    def _perform(self, action: Action) -> None:
        self._may_be_watched()
        try:
            perform(self.client, self.id, action)
        finally:
            self._may_be_watched()
            with self.lock:
                self._pending_actions -= 1

    def _apply_control(self, event: Control, now: float) -> None:
        """Apply one token change, stop or reset (caller holds the lock)."""
        if event.kind == "token" and event.arm in self.devices:
            self.state.on_device_token(event.arm, event.present, now)
        elif event.kind == "token" and event.arm is not None:
            self.state.on_token(event.arm, event.present, now)
        elif event.kind == "stop" and event.stop is None:
            # The agents stopped on it themselves. It is not repeated: an id made up here would
            # be one no agent saw, and a heartbeat composed before an operator's reset would
            # re-latch it after that reset.
            self.undecodable_stops += 1
            log.warning("a stop on %s did not decode: %s", event.arm or "all", event.why[:200])
        elif event.kind == "stop" and event.stop is not None:
            request = event.stop
            new = not self.stops.knows(request.stop_id)  # its repeats are not logged again
            if self.stops.on_stop(event.arm or FLEET, request) and new:
                log.warning(
                    "stop %s by %s on %s%s",
                    request.stop_id[:24],
                    request.source,
                    event.arm or "all",
                    # no reason given: no dangling colon
                    f": {request.reason[:200]}" if request.reason else " (no reason given)",
                )
        elif event.kind == "reset":
            self.stops.on_reset(event.arm or FLEET)

    # ------------------------------------------------------------------ multi-arm commands

    def _serve(self, payload: bytes, principal: str) -> m.MultiArmReply:
        """One ``coordinator/cmd/<principal>`` request (on a desk worker). The coordinator
        commands the arms as itself; with security on, only a commander may ask it."""
        role = self.inventory.role_of(principal)
        if self.inventory.security.enabled and role not in COMMANDERS:
            why = f"principal {principal!r} (role {role}) may not command arms"
            return error_reply(ErrorCode.REJECTED, why)
        try:
            return self.command(payloads.MULTI_REQUEST.decode(payload))
        except (payloads.PayloadError, InventoryError) as exc:
            return error_reply(ErrorCode.PARAMETER, str(exc))

    def command(self, request: m.MultiArmRequest) -> m.MultiArmReply:
        """Send one command to every arm of ``request.target`` as this coordinator (the owner);
        with sync, all arms get the same start time. Raises InventoryError for a bad target."""
        arms = self.inventory.resolve(request.target)
        refused = self._avoided(arms, request) or self._not_all_ready(arms, request)
        if refused is not None:
            return refused
        # Its own owner and its own stamps: requesters' clocks may disagree, and the agents
        # serve one owner's commands in stamp order.
        changes: dict[str, object] = {"owner": self.id, "stamp_ns": None}
        if request.sync and len(arms) > 1 and not isinstance(request.command, m.Hold):
            # (a hold takes the pose of the moment it is written: it has no start time)
            lead = (
                request.lead_s
                if request.lead_s is not None
                else self.inventory.coordinator.sync_lead_s
            )
            changes["start_at_ns"] = start_at_ns(lead)
        command = msgspec.structs.replace(request.command, **changes)
        self._may_be_watched()  # before the first agent starts watching: copies from now
        replies = dict(zip(arms, self._pool.map(lambda a: self.client.command(a, command), arms)))
        self._may_be_watched()
        written = [r.written_ns for r in replies.values() if r.ok and r.written_ns is not None]
        skew = round((max(written) - min(written)) / 1e6, 3) if len(written) > 1 else None
        return m.MultiArmReply(all(r.ok for r in replies.values()), replies, skew)

    def _not_all_ready(self, arms: list[str], request: m.MultiArmRequest) -> m.MultiArmReply | None:
        """A synchronized move is all or nothing: refused before any arm gets a start time
        when one of them cannot take part (unless the request allows ``partial``)."""
        if not request.sync or request.partial or len(arms) < 2:
            return None
        if isinstance(request.command, (m.Hold, m.Release)):
            return None  # not a move: each arm on its own is right
        now = time.monotonic()
        with self.lock:
            unready = {a: why for a in arms if (why := self.state.unready(a, now)) is not None}
        if not unready:
            return None
        why = "; ".join(f"{arm}: {reason}" for arm, reason in unready.items())
        return error_reply(
            ErrorCode.REJECTED,
            f"synchronized move refused, no arm moved ({why}); --partial moves the others",
        )

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
                        return error_reply(ErrorCode.REJECTED, why)
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
        if self._closed:
            return
        self._closed = True
        self.stopping.set()  # (already set if a thread failed: that stopped the heartbeat)
        for thread in self._threads:
            if thread.is_alive() and thread is not threading.current_thread():
                thread.join(timeout=2.0)
        self.desk.close()
        self._pool.shutdown(wait=False, cancel_futures=True)
        for entity in self._declared:
            entity.undeclare()
        for publisher in (self._heartbeat_pub, self._state_pub, self._report_pub, self._diag_pub):
            publisher.undeclare()
        self.client.close()
        self.datagram.close()
        close_bounded(self.session, "session")

    def __enter__(self) -> Coordinator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
