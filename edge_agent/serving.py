"""The agent's ``commands`` thread: key-space commands in, checked D1 commands out.

Takes queries off the relay's queue, decodes and checks them (limits, link, power, stop latch,
lease, lifetime), assigns seqs, registers them in flight (under the agent's lock, before any
write, so no ack can arrive unmatched) and writes them to DDS, now or at a synchronized start.
Replies are sent by whichever thread completes the command (see ``EdgeAgent``).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import TYPE_CHECKING

import msgspec

from edge_agent.commands import InFlight, Refused, plan
from edge_agent.relay import IncomingQuery
from edge_agent.safety import LeaseRefused
from edge_agent.slots import ArmSlot, Outbox
from fleet.d1 import protocol as p
from fleet.wire import messages as m
from fleet.wire import payloads
from fleet.wire.messages import ErrorCode, ErrorInfo

if TYPE_CHECKING:
    from edge_agent.agent import EdgeAgent

log = logging.getLogger("edge_agent.commands")

MAX_START_DELAY_S = 5.0
"""A synchronized start further ahead than this is refused (a clock problem, not a plan)."""


class CommandService:
    """Serves ``arm/<arm>/cmd`` for every arm of the agent."""

    def __init__(self, agent: EdgeAgent) -> None:
        self.agent = agent
        self._timers: list[threading.Timer] = []  # synchronized starts not yet written

    def cancel_pending_starts(self) -> None:
        """Shutdown: no delayed start may fire once the agent stops (it writes nothing anyway)."""
        for timer in self._timers:
            timer.cancel()

    def run(self) -> None:
        """The ``commands`` thread: serve queries until the agent stops."""
        while not self.agent.stopping.is_set():
            try:
                item = self.agent.relay.commands.get(timeout=0.2)
            except queue.Empty:
                continue
            self._handle(item)

    def _handle(self, item: IncomingQuery) -> None:
        now = time.monotonic()
        slot = self.agent.slots[item.arm]
        try:
            command = payloads.COMMAND.decode(item.payload)
        except msgspec.DecodeError as exc:
            with self.agent.lock:
                slot.tracker.rejected += 1
                slot.tracker.last_error = f"bad command payload: {exc}"
            self._refuse(item, ErrorCode.PARAMETER, f"bad command payload: {exc}", now)
            return
        with self.agent.lock:
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
        moves = isinstance(command, m.MOTION_OPS) or (isinstance(command, m.Torque) and command.on)
        if flight is None:  # a lease release: nothing goes to the arm
            self._reply_now(item, now)
        elif delay_s > 0:
            write = self.agent.guarded(lambda: self._write_all(item.arm, texts, flight, moves))
            timer = threading.Timer(delay_s, write)
            timer.name = f"start-{item.arm}"
            timer.daemon = True
            self._timers = [t for t in self._timers if t.is_alive()] + [timer]
            timer.start()
        else:
            self._write_all(item.arm, texts, flight, moves)

    def _accept(
        self, slot: ArmSlot, item: IncomingQuery, command: m.ArmCommand, now: float
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
        if (
            isinstance(command, m.MOTION_OPS)
            and command.owner in self.agent.safety_loop.last_heartbeat_s
        ):
            safety.watch(command.owner)
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

    def _write_all(self, arm: str, texts: list[str], flight: InFlight, moves: bool) -> None:
        """Write a command's DDS strings (now, or from a synchronized-start timer).

        A stop may latch at any moment, on the safety thread: motion is not written once the
        arm is latched, and if a stop latched while it was being written, the stop's action is
        written again after it, so the last word the arm hears is the stop's.
        """
        pubs = self.agent.relay.publishers[arm]
        slot = self.agent.slots[arm]
        for text in texts:
            with self.agent.lock:
                if flight.error is not None:
                    return  # cancelled meanwhile
                if moves and (slot.safety.latched or self.agent.stopping.is_set()):
                    flight.fail(ErrorCode.REJECTED, "stopped before its start time: not written")
                    out = Outbox()
                    self.agent.collect_finished(slot, time.monotonic(), out)
                    latched = None
                else:
                    out, latched = None, slot.safety.stop
            if out is not None:
                self.agent.flush(out)
                return
            ok = self.agent.link.write(arm, text)
            with self.agent.lock:
                flight.written_ns = flight.written_ns or time.time_ns()
                stopped_meanwhile = moves and slot.safety.stop is not latched
            if stopped_meanwhile:
                self.agent.safety_loop.rewrite_stop(arm)
            self.agent.contact.on_sent(arm, text)
            if not ok:
                with self.agent.lock:
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
        self.agent.flush(Outbox(replies=[(item.query, reply)]))

    def _refuse(self, item: IncomingQuery, code: ErrorCode, message: str, started: float) -> None:
        self._reply_now(item, started, ErrorInfo(int(code), message))
