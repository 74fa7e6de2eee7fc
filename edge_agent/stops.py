"""The agent's protective stop, reset, heartbeat watchdog: the ``safety`` thread, for every
robot it serves (arms and devices alike: one set of rules; only the action written differs).

A stop is acted on locally first, whatever the coordinator does: the agent latches the arm,
writes the arm's stop action to DDS (``hold``: the fresh measured angles become the target;
``unload``; ``power_off``), cancels commands in flight, and acknowledges on
``arm/<arm>/estop/ack``. It then re-sends the action every 0.2 s until feedback shows the arm
still, and acknowledges again with the time it was seen still. Nothing here waits for the arm's
own acks: a stop is confirmed by feedback (``power=0`` has been reported acknowledged and
ignored).

A device's stop is the same latch with its kind's action (``DeviceDriver.write_stop``: a
gripper's hold, a G1's stop_move or damp), repeated until the device's own state confirms it
(``stop_confirmed``, checked on the relay thread). A stop or reset of an arm also applies to the
devices mounted on it (``mounted``).

Each tick the thread first acts on every stop and reset that arrived (in arrival order), then on
the newest heartbeat of each source, then on the watchdog and the stop repeats. A stop payload
that does not decode, or that found the inbox full, still stops the arms it names.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from itertools import count

from edge_agent.inbox import ResetEvent, SafetyInbox, StopEvent
from edge_agent.latches import LatchStore
from edge_agent.relay import ZenohRelay
from fleet.devices.safety import ResetOutcome, seconds_ahead
from fleet.devices.unit import Later, Outbox, Unit, UnitServer
from fleet.guard import ThreadGuard
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, encode

log = logging.getLogger("edge_agent.stops")

SAFETY_TICK_S = 0.05
HEARTBEAT_FORGET_S = 30.0
"""A heartbeat source silent this long is forgotten (its arms' watchdogs tripped long ago)."""
MAX_HEARTBEAT_SOURCES = 256
"""Heartbeat sources remembered at once; the oldest that watches no arm is forgotten first."""
CONFIRM_REPEAT_S = 1.0
CONFIRM_REPEAT_EVERY_S = 0.05
"""A unit's confirmation ("still") is sent again on the datagram path every 50 ms for 1 s (20
copies) without waiting for the sender's repeats: otherwise each copy that reached the client
needed a repeat that reached the agent first. At 30 % loss per link a copy crosses four links
each way (24 % arrive): a round trip succeeded for 6 % of the client's repeats (10 a second),
and in the lab 1-3 of 25 units' stops went unconfirmed for 10 s while the TCP path delivered
nothing. One-way, 20 copies all lost is 0.76^20 = 0.4 %, then the repeats' acks go on."""

Flush = Callable[[Outbox], None]


class SafetyLoop:
    """Acts on stops, resets and heartbeats; runs the watchdog and the stop repeats."""

    def __init__(
        self,
        lock: threading.Lock,
        slots: dict[str, Unit],
        servers: dict[str, UnitServer],
        relay: ZenohRelay,
        inbox: SafetyInbox,
        flush: Flush,
        stopping: threading.Event,
        guard: ThreadGuard,
        latches: LatchStore,
        mounted: dict[str, list[str]] | None = None,
    ) -> None:
        self._lock = lock
        self._slots = slots
        self._mounted = mounted or {}
        """Arm id -> the devices mounted on it that this agent serves (a stop of the arm
        stops them too; the arm may be served by another agent)."""
        self._servers = servers
        """How a stop acts on each unit: its kind's ``UnitServer``
        (``fleet/devices/unit.py``), the only kind-specific part."""
        self._relay = relay
        self._inbox = inbox
        self._flush = flush
        self._stopping = stopping
        self._latches = latches
        self.last_heartbeat_s: dict[str, float] = {}  # guarded by lock (read by commands)
        self._confirming: dict[str, tuple[float, float]] = {}
        """Unit -> (repeat its confirmation until, next copy at), monotonic; guarded by lock."""
        self._undecodable_ids = count(1)
        self.thread = guard.thread(self._run, "safety")

    def _run(self) -> None:
        while not self._stopping.is_set():
            self._inbox.wake.wait(SAFETY_TICK_S)
            self._inbox.wake.clear()
            control, beats = self._inbox.take()
            for event in control:
                if isinstance(event, StopEvent):
                    self._on_stop(event)
                else:
                    self._on_reset(event)
            for source, beat, arrived_s in beats:
                self._on_heartbeat(source, beat, arrived_s)
            self._tick()

    # ------------------------------------------------------------------ events

    def _targets(self, unit: str | None) -> list[str]:
        """Every unit for None; else ``unit`` (when served here) and the devices mounted on it."""
        if unit is None:
            return list(self._slots)
        return ([unit] if unit in self._slots else []) + self._mounted.get(unit, [])

    def _on_stop(self, event: StopEvent) -> None:
        if event.request is not None:
            self.stop_arms(self._targets(event.arm), event.request)
            return
        # Undecodable, or dropped by a flood: it still stops. An arm already latched just
        # acknowledges its current stop again (a flood must not rewrite the stop at its rate).
        now_ns = time.time_ns()
        request = m.StopRequest(
            stamp_ns=now_ns,
            source="unknown",
            stop_id=f"undecodable-{os.getpid()}-{next(self._undecodable_ids)}",
            reason=event.why[:900],
        )
        with self._lock:
            free = [a for a in self._targets(event.arm) if not self._slots[a].safety.latched]
            latched = [a for a in self._targets(event.arm) if a not in free]
        self.stop_arms(free, request)
        self._reack(latched)

    def _on_reset(self, event: ResetEvent) -> None:
        request = event.request
        targets = self._targets(event.arm)
        ahead_s = seconds_ahead(request.stamp_ns, time.time_ns())
        if ahead_s is not None and targets:
            self._inbox.count_bad_stamp()  # once per reset; each unit's refusal is logged
        acks: list[tuple[str, bytes]] = []
        for unit in targets:
            outcome, received_ns = self.reset(unit, request.source, request.stamp_ns)
            if request.reset_id is not None:
                ack = m.ResetAck(
                    unit=unit,
                    reset_id=request.reset_id,
                    outcome=outcome.outcome,  # type: ignore[arg-type]
                    detail=outcome.detail[:1000],
                    received_ns=received_ns,
                )
                acks.append((unit, encode(ack)))
        for unit, data in acks:
            self._relay.reset_ack(unit).put(data)

    def _on_heartbeat(self, source: str, beat: m.Heartbeat, arrived_s: float) -> None:
        with self._lock:
            self.last_heartbeat_s[source] = arrived_s
        for target, request in beat.stops.items():
            arms = self._targets(None if target == "*" else target)
            if not arms:
                continue  # another agent's robot
            # Heartbeats repeat stops 10 times a second: no fresh ack for each repeat.
            self.stop_arms(arms, request, reack=False)

    # ------------------------------------------------------------------ stop and reset

    def stop_arms(self, arms: list[str], request: m.StopRequest, reack: bool = True) -> None:
        """Latch every arm of ``arms`` and write all their stop commands to DDS first, then
        publish acks, status and replies: the last arm's DDS write does not wait for the
        first arm's Zenoh traffic (1 ms per arm when done arm by arm). A repeat of the latched
        stop is acknowledged again (``reack``); a repeat of a reset stop is ignored. No stamp
        makes a stop ignored: one far ahead of this host's clock is counted and latches."""
        now, now_ns = time.monotonic(), time.time_ns()
        if reack and arms and seconds_ahead(request.stamp_ns, now_ns) is not None:
            self._inbox.count_bad_stamp()  # a heartbeat's repeats are counted once, put direct
        out = Outbox()
        latched: list[str] = []
        repeats: list[str] = []
        with self._lock:
            for arm in arms:
                slot = self._slots[arm]
                safety = slot.safety
                if safety.is_current(request.stop_id):
                    if reack:
                        repeats.append(arm)  # the first ack may have been lost
                    continue
                if reack and request.stop_id in safety.superseded_ids:
                    # Put directly by its sender, who waits for an ack: it becomes the latched
                    # stop (once only heard from a heartbeat, or replaced by a newer one).
                    safety.superseded_ids.remove(request.stop_id)
                elif not reack and safety.latched:
                    # A heartbeat repeating another stop of an arm already stopped: nothing to
                    # do physically; remembered so that the reset releases it too (a flood of
                    # such repeats must cost a list entry, not a stop write each).
                    safety.note_also_stopped_by(
                        request.stop_id, request.source, request.reason, request.stamp_ns, now_ns
                    )
                    continue
                action = slot.stop_action
                if not safety.latch(
                    request.stop_id,
                    request.source,
                    request.reason,
                    now,
                    now_ns,
                    action,
                    request.stamp_ns,
                ):
                    continue
                self._servers[arm].latched(arm, now, out)
                latched.append(arm)
        self._reack(repeats)
        if not latched:
            return
        for arm in latched:
            self._servers[arm].started(arm, now)
        later: list[Callable[[], None]] = []  # mirrors and observers, after every DDS write
        for arm in latched:
            self._write_stop(arm, request.stop_id, later)
        acks = Outbox()
        with self._lock:
            for arm in latched:
                slot = self._slots[arm]
                ack = self._ack(arm, slot)
                if ack is not None:
                    acks.puts.append((self._relay.stop_ack(arm), encode(ack)))
                status = self._servers[arm].status(arm, now, now_ns)
                if status is not None:
                    out.puts.append(status)
        self._flush(acks)
        self._flush(out)
        for tell in later:
            tell()
        for arm in latched:  # after every arm's stop is written: a file sync takes milliseconds
            self._latches.remember(arm, request)
        with self._lock:
            actions = {self._slots[a].stop_action for a in latched}
        log.warning(
            "stopped %s by %s (%s)", ", ".join(latched), request.source, "/".join(sorted(actions))
        )

    def _reack(self, arms: list[str]) -> None:
        out = Outbox()
        with self._lock:
            for arm in arms:
                ack = self._ack(arm, self._slots[arm])
                if ack is not None:
                    out.puts.append((self._relay.stop_ack(arm), encode(ack)))
        self._flush(out)

    def _write_stop(self, arm: str, stop_id: str | None, later: Later | None = None) -> bool:
        """Write the stop action of the stop latched on ``arm`` (``stop_id``; None: whichever
        is latched), composed at the moment of writing (``UnitServer.write``). True if it is
        this stop's first write (a hold without a fresh pose is written by a later repeat)."""
        return self._servers[arm].write(arm, stop_id, later)

    def _ack(self, arm: str, slot: Unit) -> m.StopAck | None:
        stop = slot.safety.stop
        if stop is None:
            return None
        return m.StopAck(
            arm=arm,
            stop_id=stop.stop_id,
            action=slot.stop_action,
            received_ns=stop.received_ns,
            dds_written_ns=stop.dds_written_ns,
            still_ns=stop.still_ns,
            confirmed_ns=stop.confirmed_ns,
            detail=stop.detail,
        )

    def reset(self, arm: str, source: str, stamp_ns: int | None = None) -> tuple[ResetOutcome, int]:
        """Release the latch (unless a stop ordered after the reset is latched, or the reset's
        stamp is far ahead: ``ArmSafety.answer_reset``); nothing moves
        (``UnitServer.released``: an arm holds its fresh measured pose, a device stays as the
        stop left it). Returns what it did and when (wall clock, ns)."""
        now, now_ns = time.monotonic(), time.time_ns()
        with self._lock:
            slot = self._slots[arm]
            outcome = slot.safety.answer_reset(stamp_ns, now_ns)
            if outcome.released is None:
                if outcome.outcome != "not_stopped":
                    log.warning("%s: reset by %s not done: %s", arm, source, outcome.detail)
                return outcome, now_ns
            slot.safety.last_reason = f"reset by {source[:128]}"
        self._latches.forget(arm)
        self._servers[arm].released(arm, now, now_ns)
        log.warning("%s reset by %s", arm, source)
        return outcome, now_ns

    # ------------------------------------------------------------------ periodic

    def _tick(self) -> None:
        """Repeat unconfirmed stops; trip the watchdog of arms whose coordinator went silent;
        forget heartbeat sources long silent."""
        now = time.monotonic()
        expired: list[tuple[str, str | None, float]] = []
        resend: list[str] = []
        with self._lock:
            self._forget_sources(now)
            for arm, slot in self._slots.items():
                watched = slot.safety.watched_by
                last = None if watched is None else self.last_heartbeat_s.get(watched)
                if slot.safety.watchdog_expired(last, now):
                    expired.append((arm, watched, now - (last if last is not None else now - 99)))
                elif slot.safety.needs_resend(now):
                    resend.append(arm)
            watching = frozenset(s.safety.watched_by for s in self._slots.values())
        self._inbox.keep_sources(frozenset(w for w in watching if w is not None))
        for arm, watched, silent in expired:
            request = m.StopRequest(
                stamp_ns=time.time_ns(),
                source="watchdog",
                stop_id=f"watchdog-{arm}-{time.time_ns()}",
                reason=f"heartbeat of coordinator {watched!r} lost for {silent:.2f} s"[:1000],
            )
            self.stop_arms([arm], request)
        for arm in resend:
            if self._write_stop(arm, None):
                self._reack([arm])  # the hold was written at last (feedback came back)
        self._repeat_confirmations(now)

    def _repeat_confirmations(self, now: float) -> None:
        """The datagram copies of each recent confirmation (``CONFIRM_REPEAT_S``)."""
        copies: list[tuple[str, bytes]] = []
        with self._lock:
            for unit, (until, due) in list(self._confirming.items()):
                ack = self._ack(unit, self._slots[unit])
                if now > until or ack is None or not ack.done:  # over, or reset meanwhile
                    del self._confirming[unit]
                elif now >= due:
                    self._confirming[unit] = (until, now + CONFIRM_REPEAT_EVERY_S)
                    copies.append((unit, encode(ack)))
        for unit, data in copies:
            self._relay.stop_ack(unit).put_datagram(data)

    def _forget_sources(self, now: float) -> None:
        """Keep the heartbeat table bounded (caller holds the lock)."""
        table = self.last_heartbeat_s
        for source in [s for s, t in table.items() if now - t > HEARTBEAT_FORGET_S]:
            del table[source]
        if len(table) > MAX_HEARTBEAT_SOURCES:
            watching = {s.safety.watched_by for s in self._slots.values()}
            spare = sorted((t, s) for s, t in table.items() if s not in watching)
            for _t, source in spare[: len(table) - MAX_HEARTBEAT_SOURCES]:
                del table[source]

    def on_still(self, arm: str, out: Outbox) -> None:
        """Feedback showed a stopped robot still: acknowledge it (caller holds the lock)."""
        ack = self._ack(arm, self._slots[arm])
        if ack is not None:
            out.puts.append((self._relay.stop_ack(arm), encode(ack)))
            now = time.monotonic()
            self._confirming[arm] = (now + CONFIRM_REPEAT_S, now + CONFIRM_REPEAT_EVERY_S)

    def restore(self, arm: str, request: m.StopRequest) -> None:
        """Latch ``arm`` with the stop it had before the agent restarted (at start-up, before
        any command is served); the stop's action is written once its feedback is fresh."""
        now, now_ns = time.monotonic(), time.time_ns()
        with self._lock:
            slot = self._slots[arm]
            action = slot.stop_action
            slot.safety.latch(request.stop_id, request.source, request.reason, now, now_ns, action)
            slot.safety.last_reason = (
                f"stopped before the agent restarted, by {request.source}: {request.reason}"
            )[:1000]
        log.warning("%s: restored the stop latched before the restart (%s)", arm, request.stop_id)

    def latch_all(self, reason: str) -> None:
        """A thread of the agent failed: latch and stop every arm before the process exits."""
        request = m.StopRequest(
            stamp_ns=time.time_ns(),
            source="edge-agent",
            stop_id=f"agent-failure-{os.getpid()}",
            reason=reason[:1000],
        )
        self.stop_arms(list(self._slots), request)


__all__ = ["ErrorCode", "SafetyLoop"]
