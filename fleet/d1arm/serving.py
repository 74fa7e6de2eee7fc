"""A D1 arm's commands, on the agent's ``commands`` thread: after the envelope checks every kind
gets (``fleet/devices/envelope.py``), the arm's own (limits, link, power, in-flight limit) and
its write.

It assigns seqs, registers them in flight (under the agent's lock, before any write, so no ack
can arrive unmatched) and writes them through the arm's writer, now or at a synchronized start
(the core's ``starts`` thread). Replies are sent by whichever thread completes the command
(``ArmSlot``'s in-flight table, collected into the agent's outbox).
"""

from __future__ import annotations

import threading
import time

from fleet.d1 import protocol as p
from fleet.d1.seq import SeqExhausted
from fleet.d1arm.commands import InFlight, Plan, plan
from fleet.d1arm.holds import NO_FRESH_POSE, allowed_while_latched, hold_command
from fleet.d1arm.slot import ArmSlot
from fleet.d1arm.writer import ArmWriter
from fleet.devices.driver import Refusal
from fleet.devices.envelope import Principals, check_lease, check_order, release
from fleet.devices.served import Flush, Schedule
from fleet.devices.unit import IncomingQuery, Outbox, owner_of
from fleet.wire import messages as m
from fleet.wire import payloads
from fleet.wire.messages import ErrorCode, ErrorInfo

MAX_START_DELAY_S = 5.0
"""A synchronized start further ahead than this is refused (a clock problem, not a plan)."""
MAX_IN_FLIGHT = 32
"""Commands in flight per arm (waiting for acks, a target or a start time); one more is
refused 4003 "busy". A real client has one or two; 65534 in flight exhausted the seqs."""


class ArmCommands:
    """Serves ``arm/<arm>/cmd`` for the arms of the agent."""

    def __init__(
        self,
        lock: threading.Lock,
        slots: dict[str, ArmSlot],
        writer: ArmWriter,
        schedule: Schedule,
        principals: Principals,
        stopping: threading.Event,
        flush: Flush,
    ) -> None:
        self._lock = lock
        self._slots = slots
        self._writer = writer
        self._schedule = schedule
        self._principals = principals
        self._stopping = stopping
        self._flush = flush

    def serve(self, item: IncomingQuery, now: float) -> None:
        """One arm command: decode, check, plan, write (now or at its start)."""
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
            except Refusal as exc:
                slot.tracker.rejected += 1
                slot.tracker.last_error = str(exc)[:1000]
                refused: Refusal | None = exc
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
        full = self._schedule(now + delay_s, write)
        if full is not None:
            self._fail(item.arm, flight, ErrorCode.BUSY, f"busy: {full}")

    def _accept(
        self, slot: ArmSlot, item: IncomingQuery, command: m.ArmCommand, now: float
    ) -> tuple[Plan, InFlight | None, float]:
        """Check, plan and register one command (caller holds the lock); raises Refusal."""
        safety = slot.safety
        principal = self._principals.check(item)
        # The lease owner is the authenticated principal (from the key), then the commander
        # the payload names: nobody can act as another principal's owner.
        owner = None if command.owner is None else owner_of(principal, command.owner)
        label = f"arm {item.arm!r}"
        if isinstance(command, m.Release):
            release(label, slot.safety, owner, now)
            return Plan((), {}), None, 0.0
        check_order(label, slot.order, principal, owner, command)
        planned = plan(command, slot.tracker, now)
        if not (isinstance(command, m.Hold) and safety.latched):  # a stop ended every lease
            check_lease(label, safety, owner, command.takeover, now)
        delay_s = 0.0
        if command.start_at_ns is not None:
            delay_s = (command.start_at_ns - time.time_ns()) / 1e9
            if delay_s > MAX_START_DELAY_S:
                raise Refusal(
                    ErrorCode.PARAMETER,
                    f"start_at_ns is {delay_s:.1f} s ahead (max {MAX_START_DELAY_S:g} s); "
                    "are the hosts' clocks synchronized?",
                )
        flights = {id(f) for f, _q in slot.in_flight.values()}
        if len(flights) >= MAX_IN_FLIGHT:
            raise Refusal(
                ErrorCode.BUSY,
                f"arm {item.arm!r} is busy: {len(flights)} commands in flight (max "
                f"{MAX_IN_FLIGHT}); wait for their replies",
            )
        try:
            seqs = tuple(slot.seqs.allocate() for _ in planned.commands)
        except SeqExhausted as exc:  # cannot happen under MAX_IN_FLIGHT; never a crash
            raise Refusal(ErrorCode.BUSY, f"arm {item.arm!r} is busy: {exc}") from None
        if (
            isinstance(command, m.MOTION_OPS)
            and owner is not None
            and self._principals.watched(principal, owner)
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
                    self._slots[arm].collect_finished(time.monotonic(), out)
            if stop_here:
                self._flush(out)
                return

    def _fail(self, arm: str, flight: InFlight, code: ErrorCode, why: str) -> None:
        out = Outbox()
        with self._lock:
            flight.fail(code, why)
            self._slots[arm].collect_finished(time.monotonic(), out)
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

    def busy(self, item: IncomingQuery, why: str) -> None:
        """Answer a query the inbox could not queue (called on the Zenoh thread)."""
        self._refuse(item, ErrorCode.BUSY, why, time.monotonic())

    def _refuse(self, item: IncomingQuery, code: ErrorCode, message: str, started: float) -> None:
        self._reply_now(item, started, ErrorInfo(int(code), message[:1000]))
