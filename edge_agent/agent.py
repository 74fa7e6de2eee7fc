"""The edge agent: relays one network's D1 arms into the key space and serves their commands.

Threads (all ours, all named):
- ``dds-feedback`` (DdsLink): decodes feedback, updates the trackers, publishes joints/status
  and completes commands whose acks or targets arrived;
- ``commands``: takes queries off the relay's queue, checks them, assigns seqs, writes DDS;
- ``housekeeping`` (20 Hz): link state, command deadlines, periodic status and diag.
``_lock`` guards the trackers and the in-flight table; it is never held across a DDS write, a
Zenoh put or a reply: state is copied under the lock and the I/O happens after.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field

import msgspec
import zenoh

from edge_agent.commands import InFlight, Refused, plan
from edge_agent.contact_edge import ContactEdge
from edge_agent.link import DdsLink
from edge_agent.relay import JSON, IncomingQuery, ZenohRelay
from edge_agent.safety import ArmSafety, LeaseRefused
from edge_agent.stops import SafetyLoop, stop_command
from edge_agent.tracker import ArmTracker
from fleet.d1 import protocol as p
from fleet.d1.seq import SeqAllocator
from fleet.inventory import Inventory
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, ErrorInfo, encode

log = logging.getLogger("edge_agent")

HOUSEKEEPING_PERIOD_S = 0.05
STATUS_PERIOD_S = 0.25
"""Status is re-published 4 times a second: late joiners learn it, and it is the agent's
heartbeat (the coordinator calls an agent offline after 1 s of silence)."""
DIAG_PERIOD_S = 1.0


MAX_START_DELAY_S = 5.0
"""A synchronized start further ahead than this is refused (a clock problem, not a plan)."""


@dataclass
class _ArmSlot:
    tracker: ArmTracker
    safety: ArmSafety
    seqs: SeqAllocator = field(default_factory=SeqAllocator)
    in_flight: dict[int, tuple[InFlight, zenoh.Query]] = field(default_factory=dict)
    joints_seq: int = 0


@dataclass
class _Outbox:
    """I/O collected under the lock, performed after it is released."""

    puts: list[tuple[zenoh.Publisher, bytes | str]] = field(default_factory=list)
    replies: list[tuple[zenoh.Query, m.CommandReply]] = field(default_factory=list)


class EdgeAgent:
    """Serves the arms ``arm_ids`` of ``inventory``. A context manager."""

    def __init__(self, inventory: Inventory, arm_ids: list[str]) -> None:
        domain_id, interface, peers = inventory.network_of(arm_ids)
        self.inventory = inventory
        self.lock = threading.Lock()
        self.arm_ids = list(arm_ids)
        self.slots = {a: self._slot(inventory, a) for a in arm_ids}
        self.stopping = threading.Event()
        suffixes = {a: inventory.arm(a).suffix for a in arm_ids}
        # DDS first: if the interface is wrong we fail before announcing anything on Zenoh.
        self.link = DdsLink(domain_id, interface, peers, suffixes, self._on_feedback)
        try:
            self.relay = ZenohRelay(inventory.fleet, arm_ids, inventory.endpoints)
        except BaseException:
            self.link.close()
            raise
        self.safety_loop = SafetyLoop(self)
        self.contact = ContactEdge(self)  # detectors and arm/<arm>/contact publishers
        self._threads = [
            self.safety_loop.thread,
            threading.Thread(
                target=self._guarded(self._command_loop), name="commands", daemon=True
            ),
            threading.Thread(
                target=self._guarded(self._housekeeping_loop), name="housekeeping", daemon=True
            ),
        ]

    def start(self) -> EdgeAgent:
        """Start relaying and serving commands."""
        self.link.start()
        for thread in self._threads:
            thread.start()
        return self

    @staticmethod
    def _slot(inventory: Inventory, arm: str) -> _ArmSlot:
        config = inventory.arm(arm)
        return _ArmSlot(ArmTracker(config), ArmSafety(config.lease_s, config.watchdog_s))

    def _guarded(self, loop):  # type: ignore[no-untyped-def]
        def run() -> None:
            try:
                loop()
            except BaseException:
                log.exception("thread %s failed", threading.current_thread().name)
                raise

        return run

    # ------------------------------------------------------------------ feedback (DDS thread)

    def _on_feedback(self, arm: str, text: str, now: float) -> None:
        stamp_ns = time.time_ns()
        pubs = self.relay.publishers[arm]
        out = _Outbox()
        with self.lock:
            slot = self.slots[arm]
            tracker = slot.tracker
            decoded = tracker.on_feedback(text, now)
            status_changed = tracker.update_link(now)
            if decoded is not None:
                message = decoded.message
                if isinstance(message, p.JointAngles):
                    slot.joints_seq += 1
                    joints = m.Joints(stamp_ns, list(message.angles_deg), slot.joints_seq)
                    out.puts.append((pubs.joints, encode(joints)))  # before the raw string
                    for flight, _query in slot.in_flight.values():
                        flight.on_angles(message.angles_deg)
                    if slot.safety.on_angles(message.angles_deg, stamp_ns):
                        self.safety_loop.on_still(arm, slot, out)
                elif isinstance(message, (p.ReceiveAck, p.ExecuteAck)):
                    entry = slot.in_flight.get(message.seq)
                    if entry is not None:
                        entry[0].on_ack(message)
                else:
                    status_changed = True
            out.puts.append((pubs.raw_feedback, text))
            if status_changed:
                out.puts.append((pubs.status, encode(tracker.status(now, stamp_ns))))
            if decoded is not None:
                self.contact.on_message(arm, slot, decoded.message, now, stamp_ns, out)
            self._collect_finished(slot, now, out)
        self.flush(out)
        self.contact.flush()  # force-limit writes, after the lock

    # ------------------------------------------------------------------ commands

    def _command_loop(self) -> None:
        while not self.stopping.is_set():
            try:
                item = self.relay.commands.get(timeout=0.2)
            except queue.Empty:
                continue
            self._handle(item)

    def _handle(self, item: IncomingQuery) -> None:
        now = time.monotonic()
        slot = self.slots[item.arm]
        try:
            command = m.command_decoder.decode(item.payload)
        except msgspec.DecodeError as exc:
            with self.lock:
                slot.tracker.rejected += 1
                slot.tracker.last_error = f"bad command payload: {exc}"
            self._refuse(item, ErrorCode.PARAMETER, f"bad command payload: {exc}", now)
            return
        with self.lock:
            slot.tracker.commands += 1
            try:
                texts, flight, delay_s = self._accept(slot, item, command, now)
            except Refused as exc:
                slot.tracker.rejected += 1
                slot.tracker.last_error = str(exc)
                refused: Refused | None = exc
            else:
                refused = None
        if refused is not None:
            self._refuse(item, refused.code, str(refused), now)
            return
        if flight is None:  # a lease release: nothing goes to the arm
            self._reply_now(item, now)
        elif delay_s > 0:
            timer = threading.Timer(delay_s, self._write_all, (item.arm, texts, flight))
            timer.name = f"start-{item.arm}"
            timer.daemon = True
            timer.start()
        else:
            self._write_all(item.arm, texts, flight)

    def _accept(
        self, slot: _ArmSlot, item: IncomingQuery, command: m.ArmCommand, now: float
    ) -> tuple[list[str], InFlight | None, float]:
        """Check, plan and register one command (caller holds the lock); raises Refused."""
        safety = slot.safety
        if isinstance(command, m.Release):
            if command.owner is None or not safety.release(command.owner):
                holder = safety.lease.owner if safety.lease else "nobody"
                raise Refused(ErrorCode.LEASE_INVALID, f"arm {item.arm!r} is held by {holder}")
            return [], None, 0.0
        if command.lifetime_s is not None and command.stamp_ns is not None:
            age_s = (time.time_ns() - command.stamp_ns) / 1e9
            if age_s > command.lifetime_s:
                raise Refused(
                    ErrorCode.TIMEOUT,
                    f"target for arm {item.arm!r} arrived {age_s * 1000:.0f} ms after it was sent, "
                    f"past its lifetime of {command.lifetime_s * 1000:.0f} ms: not executed",
                )
        planned = plan(command, slot.tracker)
        if not isinstance(command, m.Hold):
            try:
                safety.check_owner(command.owner, command.takeover, now)
            except LeaseRefused as exc:
                raise Refused(ErrorCode.LEASE_EXISTS, f"arm {item.arm!r} is {exc}") from None
        delay_s = 0.0
        if command.start_at_ns is not None:
            delay_s = (command.start_at_ns - time.time_ns()) / 1e9
            if delay_s > MAX_START_DELAY_S:
                raise Refused(
                    ErrorCode.PARAMETER,
                    f"start_at_ns is {delay_s:.1f} s ahead (max {MAX_START_DELAY_S:g} s); "
                    "are the hosts' clocks synchronized?",
                )
        if isinstance(command, m.MOTION_OPS) and command.owner in self.safety_loop.last_heartbeat_s:
            safety.watch(command.owner, planned.targets_deg)
        seqs = tuple(slot.seqs.allocate() for _ in planned.commands)
        texts = [p.encode_command(c, s) for c, s in zip(planned.commands, seqs)]
        config = slot.tracker.config
        start = now + max(0.0, delay_s)
        flight = InFlight(
            arm=item.arm,
            seqs=seqs,
            started_s=now,
            recv_deadline_s=start + config.recv_ack_timeout_s,
            exec_deadline_s=start + config.exec_ack_timeout_s,
            reach_deadline_s=start + command.timeout_s if command.wait_reached else None,
            targets_deg=planned.targets_deg,
            tolerance_deg=command.tolerance_deg,
        )
        for seq in seqs:
            slot.in_flight[seq] = (flight, item.query)
        return texts, flight, delay_s

    def _write_all(self, arm: str, texts: list[str], flight: InFlight) -> None:
        """Write a command's DDS strings (now, or from a synchronized-start timer)."""
        pubs = self.relay.publishers[arm]
        for text in texts:
            with self.lock:
                if flight.error is not None:
                    return  # cancelled meanwhile (a stop latched before the start time)
            ok = self.link.write(arm, text)
            self.contact.on_sent(arm, text)
            flight.written_ns = flight.written_ns or time.time_ns()
            if not ok:
                with self.lock:
                    flight.fail(ErrorCode.SEND_FAILED, "the DDS write failed (maybe sent)")
            pubs.raw_command.put(text)

    def _reply_now(
        self, item: IncomingQuery, started: float, error: ErrorInfo | None = None
    ) -> None:
        """Reply to a command that sent nothing to the arm (a refusal, a lease release)."""
        reply = m.CommandReply(
            ok=error is None,
            arm=item.arm,
            seq=None,
            received=False,
            executed=None,
            reached=None,
            latency_ms=round((time.monotonic() - started) * 1000.0, 3),
            error=error,
        )
        self.flush(_Outbox(replies=[(item.query, reply)]))

    def cancel_in_flight(self, slot: _ArmSlot, now: float, why: str, out: _Outbox) -> None:
        """Fail every command in flight on ``slot`` (caller holds the lock)."""
        for flight, _query in slot.in_flight.values():
            flight.fail(ErrorCode.REJECTED, why)
        self._collect_finished(slot, now, out)

    def _refuse(self, item: IncomingQuery, code: ErrorCode, message: str, started: float) -> None:
        self._reply_now(item, started, ErrorInfo(int(code), message))

    # ------------------------------------------------------------------ housekeeping

    def _housekeeping_loop(self) -> None:
        next_status = next_diag = 0.0
        while not self.stopping.wait(HOUSEKEEPING_PERIOD_S):
            now = time.monotonic()
            stamp_ns = time.time_ns()
            periodic = now >= next_status
            if periodic:
                next_status = now + STATUS_PERIOD_S
            diag = now >= next_diag
            if diag:
                next_diag = now + DIAG_PERIOD_S
            out = _Outbox()
            with self.lock:
                for arm, slot in self.slots.items():
                    tracker = slot.tracker
                    pubs = self.relay.publishers[arm]
                    if tracker.update_link(now) or periodic:
                        out.puts.append((pubs.status, encode(tracker.status(now, stamp_ns))))
                    if diag:
                        out.puts.append((pubs.diag, encode(tracker.diag(now, stamp_ns))))
                    for flight, _query in list(slot.in_flight.values()):
                        flight.on_time(now, tracker.angles_deg)
                    self._collect_finished(slot, now, out)
            self.flush(out)

    def _collect_finished(self, slot: _ArmSlot, now: float, out: _Outbox) -> None:
        """Move finished commands from the in-flight table to ``out`` (caller holds the lock)."""
        finished: dict[int, tuple[InFlight, zenoh.Query]] = {}
        for seq, (flight, query) in list(slot.in_flight.items()):
            if flight.done:
                del slot.in_flight[seq]
                slot.seqs.release(seq)
                finished[id(flight)] = (flight, query)
        for flight, query in finished.values():
            reply = flight.reply(now)
            if reply.error is not None:
                slot.tracker.last_error = reply.error.message
                if reply.error.code == ErrorCode.TIMEOUT:
                    slot.tracker.ack_timeouts += 1
            out.replies.append((query, reply))

    def flush(self, out: _Outbox) -> None:
        for publisher, payload in out.puts:
            publisher.put(payload)
        for query, reply in out.replies:
            query.reply(query.key_expr, encode(reply), encoding=JSON)
            query.drop()

    # ------------------------------------------------------------------ state access

    def tracker(self, arm: str) -> ArmTracker:
        """The tracker of ``arm`` (read it under no assumption of consistency)."""
        return self.slots[arm].tracker

    # ------------------------------------------------------------------ shutdown

    def close(self) -> None:
        """Shutdown order: stop taking commands -> hold every arm still moving (nobody will
        command it any more) -> stop the loops and join -> stop DDS -> undeclare Zenoh (tokens
        first, so the fleet sees the agent leave) and close the session. Idempotent."""
        if self.stopping.is_set():
            return
        self.stopping.set()
        self._hold_moving_arms()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=2.0)
        self.link.close()
        self.relay.close()

    def _hold_moving_arms(self) -> None:
        texts: list[tuple[str, str]] = []
        with self.lock:
            for arm, slot in self.slots.items():
                tracker = slot.tracker
                if tracker.link != "ok" or slot.safety.standstill.still:
                    continue
                command = stop_command("hold", tracker.angles_deg)
                if command is not None and tracker.powered is not False:
                    seq = slot.seqs.allocate()
                    texts.append((arm, p.encode_command(command, seq)))
        for arm, text in texts:
            self.link.write(arm, text)
            log.info("arm %s was moving: held it before shutting down", arm)

    def __enter__(self) -> EdgeAgent:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
