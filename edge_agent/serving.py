"""The agent's ``commands`` thread: key-space commands in, checked robot commands out.

Takes queries off the command inbox, decodes and checks them. Every kind gets the same envelope
checks, in one place: the principal and its role, duplicates / out-of-order / lifetime
(``ordering.py``), the lease (``<principal>/<owner>``, takeover, release), the watchdog's watch
of a coordinator's motion, and the stop latch at the moment of writing (under the robot's write
lock). A device's own checks and its write are its driver's (``DeviceDriver.execute``); an arm's
(limits, link, power, in-flight limit) are here: it assigns seqs, registers them in flight
(under the agent's lock, before any write, so no ack can arrive unmatched) and writes them
through the arm's writer, now or at a synchronized start. Replies are sent by whichever thread
completes the command (see ``EdgeAgent``). Queries the inbox could not queue are answered 4003
"busy" (``busy``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from edge_agent.commands import InFlight, Plan, Refused, plan
from edge_agent.holds import NO_FRESH_POSE, allowed_while_latched, hold_command
from edge_agent.inbox import CommandInbox, IncomingQuery, owner_of
from edge_agent.ordering import CommandOrder
from edge_agent.safety import ArmSafety, LeaseRefused
from edge_agent.scheduler import SchedulerFull, StartScheduler
from edge_agent.slots import ArmSlot, DeviceSlot, Outbox
from edge_agent.writer import ArmWriter
from fleet.d1 import protocol as p
from fleet.d1.seq import SeqExhausted
from fleet.devices.base import DeviceCommand, DeviceReply, Release
from fleet.devices.driver import Refusal, error_reply
from fleet.inventory import Inventory
from fleet.security_config import COMMANDERS
from fleet.wire import messages as m
from fleet.wire import payloads
from fleet.wire.messages import ErrorCode, ErrorInfo

Envelope = m.ArmCommand | DeviceCommand
"""A command with the envelope every kind shares (owner, takeover, stamp_ns, lifetime_s)."""

log = logging.getLogger("edge_agent.commands")

MAX_START_DELAY_S = 5.0
"""A synchronized start further ahead than this is refused (a clock problem, not a plan)."""
MAX_IN_FLIGHT = 32
"""Commands in flight per arm (waiting for acks, a target or a start time); one more is
refused 4003 "busy". A real client has one or two; 65534 in flight exhausted the seqs."""

Collect = Callable[[ArmSlot, float, Outbox], None]
Flush = Callable[[Outbox], None]


class CommandService:
    """Serves ``arm/<arm>/cmd`` and ``<kind>/<device>/cmd`` for every robot of the agent."""

    def __init__(
        self,
        lock: threading.Lock,
        slots: dict[str, ArmSlot],
        devices: dict[str, DeviceSlot],
        reply_device: Callable[[IncomingQuery, DeviceReply, float], None],
        writer: ArmWriter,
        inbox: CommandInbox,
        scheduler: StartScheduler,
        hooks: tuple[Collect, Flush],
        heartbeats: dict[str, float],
        stopping: threading.Event,
        inventory: Inventory,
    ) -> None:
        self._lock = lock
        self._slots = slots
        self._devices = devices
        self._reply_device = reply_device
        self._writer = writer
        self._inbox = inbox
        self._scheduler = scheduler
        self._collect, self._flush = hooks
        self._heartbeats = heartbeats  # coordinator -> last heartbeat (guarded by lock)
        self._stopping = stopping
        self._inventory = inventory

    def run(self) -> None:
        """The ``commands`` thread: serve queries until the agent stops."""
        while not self._stopping.is_set():
            item = self._inbox.take()
            if item is None:
                self._inbox.wake.wait(0.2)
                continue
            self._handle(item)

    def _handle(self, item: IncomingQuery) -> None:
        now = time.monotonic()
        if item.arm in self._devices:
            self._handle_device(item, self._devices[item.arm], now)
            return
        slot = self._slots[item.arm]
        try:
            command = payloads.COMMAND.decode(item.payload)
        except payloads.PayloadError as exc:
            op = payloads.unknown_op(item.payload)
            code, why = (
                (ErrorCode.NOT_IMPLEMENTED, f"unknown op {op!r} (known: {sorted(m.COMMAND_OPS)})")
                if op is not None
                else (ErrorCode.PARAMETER, str(exc))
            )
            with self._lock:
                slot.tracker.rejected += 1
                slot.tracker.last_error = why[:1000]
            self._refuse(item, code, why, now)
            return
        with self._lock:
            slot.tracker.commands += 1
            try:
                planned, flight, delay_s = self._accept(slot, item, command, now)
            except Refused as exc:
                slot.tracker.rejected += 1
                slot.tracker.last_error = str(exc)[:1000]
                refused: Refused | None = exc
            else:
                refused = None
        if refused is not None:
            self._refuse(item, refused.code, str(refused), now)
            return
        if flight is None:  # a lease release: nothing goes to the arm
            self._reply_now(item, now)
            return

        def write() -> None:
            self._write_all(item.arm, command, planned, flight)

        if delay_s <= 0:
            write()
            return
        try:
            self._scheduler.schedule(now + delay_s, write)
        except SchedulerFull as exc:
            self._fail(item.arm, flight, ErrorCode.BUSY, f"busy: {exc}")

    def _accept(
        self, slot: ArmSlot, item: IncomingQuery, command: m.ArmCommand, now: float
    ) -> tuple[Plan, InFlight | None, float]:
        """Check, plan and register one command (caller holds the lock); raises Refused."""
        safety = slot.safety
        principal = self._check_principal(item)
        # The lease owner is the authenticated principal (from the key), then the commander
        # the payload names: nobody can act as another principal's owner.
        owner = None if command.owner is None else owner_of(principal, command.owner)
        label = f"arm {item.arm!r}"
        if isinstance(command, m.Release):
            _release(label, slot.safety, owner, now)
            return Plan((), {}), None, 0.0
        _check_order(label, slot.order, principal, owner, command)
        planned = plan(command, slot.tracker, now)
        if not (isinstance(command, m.Hold) and safety.latched):  # a stop ended every lease
            _check_lease(label, safety, owner, command.takeover, now)
        delay_s = 0.0
        if command.start_at_ns is not None:
            delay_s = (command.start_at_ns - time.time_ns()) / 1e9
            if delay_s > MAX_START_DELAY_S:
                raise Refused(
                    ErrorCode.PARAMETER,
                    f"start_at_ns is {delay_s:.1f} s ahead (max {MAX_START_DELAY_S:g} s); "
                    "are the hosts' clocks synchronized?",
                )
        flights = {id(f) for f, _q in slot.in_flight.values()}
        if len(flights) >= MAX_IN_FLIGHT:
            raise Refused(
                ErrorCode.BUSY,
                f"arm {item.arm!r} is busy: {len(flights)} commands in flight (max "
                f"{MAX_IN_FLIGHT}); wait for their replies",
            )
        try:
            seqs = tuple(slot.seqs.allocate() for _ in planned.commands)
        except SeqExhausted as exc:  # cannot happen under MAX_IN_FLIGHT; never a crash
            raise Refused(ErrorCode.BUSY, f"arm {item.arm!r} is busy: {exc}") from None
        if (
            isinstance(command, m.MOTION_OPS)
            and owner is not None
            and self._watched(principal, owner)
        ):
            safety.watch(owner, now)
        config = slot.tracker.config
        start = now + max(0.0, delay_s)
        flight = InFlight(
            arm=item.arm,
            seqs=seqs,
            started_s=now,
            recv_deadline_s=start + config.recv_ack_timeout_s,
            exec_deadline_s=start + slot.acks.exec_timeouts.longest(planned.commands),
            reach_deadline_s=start + command.timeout_s if command.wait_reached else None,
            targets_deg=planned.targets_deg,
            tolerance_deg=command.tolerance_deg,
        )
        for seq in seqs:
            slot.in_flight[seq] = (flight, item.query)
        slot.order.record(principal, owner, command.stamp_ns)
        return planned, flight, delay_s

    def _watched(self, principal: str, owner: str) -> bool:
        """Motion by this owner is watched: it publishes heartbeats (a player, a mirror), or it
        is a coordinator (watched even before this agent heard its first beat)."""
        return owner in self._heartbeats or self._inventory.role_of(principal) == "coordinator"

    def _handle_device(self, item: IncomingQuery, slot: DeviceSlot, now: float) -> None:
        """One device command: the envelope checked here as for an arm, then, under the
        device's write lock, the latch and the driver's own checks and write."""
        driver, label = slot.driver, f"{slot.kind} {item.arm!r}"
        try:
            command = driver.commands.decode(item.payload)
        except payloads.PayloadError as exc:
            op = payloads.unknown_op(item.payload, payloads.ops_of(driver.commands))
            code, why = (
                (ErrorCode.NOT_IMPLEMENTED, f"unknown op {op!r} for {label}")
                if op is not None
                else (ErrorCode.PARAMETER, str(exc))
            )
            self._refuse_device(item, slot, code, why, now)
            return
        try:
            with self._lock:
                principal = self._check_principal(item)
                owner = None if command.owner is None else owner_of(principal, command.owner)
                released = isinstance(command, Release)
                if released:
                    _release(label, slot.safety, owner, now)
            if released:
                self._reply_device(item, DeviceReply(ok=True, device=item.arm), now)
                return
            with self._lock:
                _check_order(label, slot.order, principal, owner, command)
                exempt = driver.allowed_while_latched(command) and slot.safety.latched
                if not exempt:
                    _check_lease(label, slot.safety, owner, command.takeover, now)
                if driver.moves(command) and owner is not None and self._watched(principal, owner):
                    slot.safety.watch(owner, now)
                slot.order.record(principal, owner, command.stamp_ns)
            with self._writer.unit_lock(item.arm):
                with self._lock:
                    latched = slot.safety.latched or self._stopping.is_set()
                    reason = slot.safety.last_reason
                if latched and not driver.allowed_while_latched(command):
                    raise Refused(
                        ErrorCode.REJECTED,
                        f"{label} is stopped ({reason}); `fleet reset {item.arm}` releases it",
                    )
                try:
                    reply = driver.execute(command, now, lambda r: self._reply_device(item, r, now))
                except Refusal as exc:
                    raise Refused(exc.code, str(exc)) from None
        except Refused as exc:
            self._refuse_device(item, slot, exc.code, str(exc), now)
            return
        if reply is not None:
            self._reply_device(item, reply, now)

    def _refuse_device(
        self, item: IncomingQuery, slot: DeviceSlot, code: ErrorCode, why: str, now: float
    ) -> None:
        with self._lock:
            slot.rejected += 1
            slot.last_error = why[:1000]
        self._reply_device(item, error_reply(item.arm, code, why), now)

    def _check_principal(self, item: IncomingQuery) -> str:
        """The principal of a command; raises Refused when it names none or, with security on,
        when its role may not command arms (the router refuses those first)."""
        principal = item.principal
        if principal is None:
            raise Refused(
                ErrorCode.PARAMETER,
                f"send commands to arm/{item.arm}/cmd/<principal>, not to a wildcard principal",
            )
        if self._inventory.security.enabled:
            role = self._inventory.role_of(principal)
            if role not in COMMANDERS:
                raise Refused(
                    ErrorCode.REJECTED,
                    f"principal {principal!r} (role {role}) may not command arms",
                )
        return principal

    def _write_all(self, arm: str, command: m.ArmCommand, planned: Plan, flight: InFlight) -> None:
        """Write a command's D1 commands (now, or at its synchronized start), each composed at
        the moment of writing: not at all once a stop latched that does not allow it (the arm
        writer serializes this with the stop's own write), and a hold with the pose of then."""
        for index, (d1, seq) in enumerate(zip(planned.commands, flight.seqs)):

            def compose(
                slot: ArmSlot, now: float, index: int = index, d1: p.Command = d1, seq: int = seq
            ) -> tuple[p.Command, int] | None:
                if flight.error is not None:
                    return None  # cancelled meanwhile (a stop, a contact)
                latched = slot.safety.latched
                if (latched or self._stopping.is_set()) and not allowed_while_latched(
                    command, slot.tracker.config.stop_action
                ):
                    flight.fail(ErrorCode.REJECTED, "a protective stop latched first: not written")
                    return None
                if index in planned.holds:
                    held = hold_command(slot.tracker, now)
                    if held is None:
                        flight.fail(ErrorCode.REJECTED, NO_FRESH_POSE.split(":")[0])
                        return None
                    d1 = held
                    if flight.targets_deg:
                        flight.targets_deg = dict(enumerate(held.angles_deg))
                # Now, under the lock, not from the write's result: the arm's ack may overtake
                # the write's return and complete the reply (a choreography's start skew then
                # lacked this arm; seen at load 11).
                flight.written_ns = flight.written_ns or time.time_ns()
                return d1, seq

            written = self._writer.write(arm, compose)
            with self._lock:
                if written is not None and not written.ok:
                    flight.fail(ErrorCode.SEND_FAILED, "the DDS write failed (maybe sent)")
                stop_here = written is None or flight.error is not None
                out = Outbox()
                if stop_here:
                    self._collect(self._slots[arm], time.monotonic(), out)
            if stop_here:
                self._flush(out)
                return

    def _fail(self, arm: str, flight: InFlight, code: ErrorCode, why: str) -> None:
        out = Outbox()
        with self._lock:
            flight.fail(code, why)
            self._collect(self._slots[arm], time.monotonic(), out)
        self._flush(out)

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
        self._flush(Outbox(replies=[(item.query, reply)]))

    def busy(self, item: IncomingQuery) -> None:
        """Answer a query the inbox could not queue (called on the Zenoh thread)."""
        why = f"{item.arm!r}: the agent is busy (its command queue is full); retry later"
        if item.arm in self._devices:
            reply = error_reply(item.arm, ErrorCode.BUSY, why)
            self._reply_device(item, reply, time.monotonic())
            return
        self._refuse(item, ErrorCode.BUSY, why, time.monotonic())

    def _refuse(self, item: IncomingQuery, code: ErrorCode, message: str, started: float) -> None:
        self._reply_now(item, started, ErrorInfo(int(code), message[:1000]))


def _release(label: str, safety: ArmSafety, owner: str | None, now_s: float) -> None:
    """``owner`` gives the robot up; raises Refused when another owner holds it. A robot held
    by nobody is already released: done, not refused (issue 26: a stop ends every lease, and
    the demo's player, releasing after each stop of its dance, filled Events and ``fleet
    diag`` with "held by nobody" refusals the user had nothing to do with)."""
    if owner is None:
        raise Refused(ErrorCode.LEASE_INVALID, f"{label}: a release names its owner")
    if safety.release(owner):
        return
    holder = safety.holder(now_s)
    if holder is not None:
        raise Refused(ErrorCode.LEASE_INVALID, f"{label} is held by {holder.owner}")


def _check_order(
    label: str, order: CommandOrder, principal: str, owner: str | None, command: Envelope
) -> None:
    """Duplicates, out-of-order commands and commands past their lifetime: Refused."""
    refusal = order.refusal(principal, owner, command.stamp_ns)
    if refusal is not None:
        raise Refused(ErrorCode.OUT_OF_ORDER, f"{label}: {refusal}")
    if command.lifetime_s is not None and command.stamp_ns is not None:
        age_s = (time.time_ns() - command.stamp_ns) / 1e9
        if age_s > command.lifetime_s:
            raise Refused(
                ErrorCode.EXPIRED,
                f"target for {label} arrived {age_s * 1000:.0f} ms after it was sent, "
                f"past its lifetime of {command.lifetime_s * 1000:.0f} ms: not executed",
            )


def _check_lease(
    label: str, safety: ArmSafety, owner: str | None, takeover: bool, now: float
) -> None:
    """Refused (3207) unless ``owner`` may move the robot now; renews or takes the lease."""
    try:
        safety.check_owner(owner, takeover, now)
    except LeaseRefused as exc:
        raise Refused(ErrorCode.LEASE_EXISTS, f"{label} is {exc}") from None
