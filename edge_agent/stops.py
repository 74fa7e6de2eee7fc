"""The agent's protective stop, reset, heartbeat watchdog: the ``safety`` thread.

A stop is acted on locally first, whatever the coordinator does: the agent latches the arm,
writes the arm's stop action to DDS (``hold``: the measured angles become the target; ``unload``;
``power_off``), cancels commands in flight, and acknowledges on ``arm/<arm>/estop/ack``. It then
re-sends the action every 0.2 s until feedback shows the arm still, and acknowledges again with
the time it was seen still. Nothing here waits for the arm's own acks: a stop is confirmed by
feedback (``power=0`` has been reported acknowledged and ignored).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import TYPE_CHECKING

import msgspec

from edge_agent.commands import clamp_to_limits
from edge_agent.relay import SafetyEvent
from edge_agent.slots import ArmSlot, Outbox
from fleet.d1 import protocol as p
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, encode

if TYPE_CHECKING:
    from edge_agent.agent import EdgeAgent

log = logging.getLogger("edge_agent.stops")

SAFETY_TICK_S = 0.05


def stop_command(action: str, angles_deg: tuple[float, ...] | None) -> p.Command | None:
    """The D1 command for a stop action; None for ``hold`` before any angle was reported."""
    if action == "unload":
        return p.SetAllTorque(0)
    if action == "power_off":
        return p.SetPower(False)
    if angles_deg is None:
        return None
    return p.SetAllAngles(clamp_to_limits(angles_deg), 0)


class SafetyLoop:
    """Drains stop/reset/heartbeat events and runs the watchdog and stop repeats."""

    def __init__(self, agent: EdgeAgent) -> None:
        self.agent = agent
        self.last_heartbeat_s: dict[str, float] = {}
        self.bad_events = 0
        self.thread = threading.Thread(target=self._run, name="safety", daemon=True)

    def _run(self) -> None:
        try:
            events = self.agent.relay.safety
            while not self.agent.stopping.is_set():
                try:
                    event = events.get(timeout=SAFETY_TICK_S)
                except queue.Empty:
                    event = None
                if event is not None:
                    self._handle(event)
                self._tick()
        except BaseException:
            log.exception("safety thread failed")
            raise

    # ------------------------------------------------------------------ events

    def _handle(self, event: SafetyEvent) -> None:
        arms = [event.arm] if event.arm is not None else list(self.agent.arm_ids)
        try:
            if event.channel == keys.ESTOP:
                self.stop_arms(arms, payloads.STOP.decode(event.payload))
            elif event.channel == keys.RESET:
                request_reset = payloads.RESET.decode(event.payload)
                for arm in arms:
                    self.reset(arm, request_reset.source)
            elif event.channel == keys.HEARTBEAT:
                self._on_heartbeat(payloads.HEARTBEAT.decode(event.payload))
        except msgspec.DecodeError as exc:
            self.bad_events += 1
            log.warning("ignored a malformed %s message: %s", event.channel, exc)

    def _on_heartbeat(self, beat: m.Heartbeat) -> None:
        now = time.monotonic()
        self.last_heartbeat_s[beat.coordinator] = now
        for target, request in beat.stops.items():
            arms = self.agent.arm_ids if target == "*" else [target]
            # Heartbeats repeat stops 10 times a second: no fresh ack for each repeat.
            self.stop_arms([a for a in arms if a in self.agent.slots], request, reack=False)

    # ------------------------------------------------------------------ stop and reset

    def stop(self, arm: str, request: m.StopRequest) -> None:
        """Latch ``arm`` and act on the stop (a repeat of a latched or reset stop is ignored)."""
        self.stop_arms([arm], request)

    def stop_arms(self, arms: list[str], request: m.StopRequest, reack: bool = True) -> None:
        """Latch every arm of ``arms`` and write all their stop commands to DDS first, then
        publish acks, status and replies: the last arm's DDS write does not wait for the
        first arm's Zenoh traffic (1 ms per arm when done arm by arm)."""
        now, now_ns = time.monotonic(), time.time_ns()
        out = Outbox()
        latched: list[tuple[str, ArmSlot, str | None]] = []
        repeats = Outbox()
        with self.agent.lock:
            for arm in arms:
                slot = self.agent.slots[arm]
                safety = slot.safety
                if reack and safety.is_current(request.stop_id):
                    # A repeat: acknowledge again, the first ack may have been lost.
                    ack = self._ack(arm, slot)
                    if ack is not None:
                        pubs = self.agent.relay.publishers[arm]
                        repeats.puts.append((pubs.stop_ack, encode(ack)))
                    continue
                if not safety.latch(request.stop_id, request.source, request.reason, now, now_ns):
                    continue
                slot.tracker.estopped = True
                slot.tracker.stop_reason = safety.last_reason
                self.agent.cancel_in_flight(slot, now, "a protective stop was latched", out)
                latched.append((arm, slot, self._stop_text(slot, now)))
        self.agent.flush(repeats)
        if not latched:
            return
        written = [self._write_dds(arm, text) for arm, _slot, text in latched]
        acks = Outbox()
        with self.agent.lock:
            for (arm, slot, text), written_ns in zip(latched, written):
                stop = slot.safety.stop
                if stop is not None and stop.stop_id == request.stop_id:
                    stop.dds_written_ns = written_ns
                pubs = self.agent.relay.publishers[arm]
                ack = self._ack(arm, slot)
                if ack is not None:
                    acks.puts.append((pubs.stop_ack, encode(ack)))
                if text is not None:
                    out.puts.append((pubs.raw_command, text))
                out.puts.append((pubs.status, encode(slot.tracker.status(now, now_ns))))
        self.agent.flush(acks)
        self.agent.flush(out)
        action = {slot.tracker.config.stop_action for _arm, slot, _text in latched}
        log.warning(
            "stopped %s by %s (%s)",
            ", ".join(arm for arm, _slot, _text in latched),
            request.source,
            "/".join(sorted(action)),
        )

    def rewrite_stop(self, arm: str) -> None:
        """Write the latched stop's action again (motion was written while it latched)."""
        with self.agent.lock:
            slot = self.agent.slots[arm]
            text = self._stop_text(slot, time.monotonic()) if slot.safety.latched else None
        self._write(arm, text)

    def _stop_text(self, slot: ArmSlot, now: float) -> str | None:
        """Encode the stop action with a fresh seq (caller holds the lock)."""
        command = stop_command(slot.tracker.config.stop_action, slot.tracker.angles_deg)
        stop = slot.safety.stop
        if stop is not None:
            stop.last_sent_s = now
        if command is None:
            return None
        seq = slot.seqs.allocate()
        slot.seqs.release(seq)  # a stop waits for standstill in feedback, not for acks
        return p.encode_command(command, seq)

    def _write_dds(self, arm: str, text: str | None) -> int | None:
        """Write to DDS only; the wall-clock time of the write, None if nothing was written."""
        if text is None:
            return None
        ok = self.agent.link.write(arm, text)
        return time.time_ns() if ok else None

    def _write(self, arm: str, text: str | None) -> int | None:
        written_ns = self._write_dds(arm, text)
        if text is not None:
            self.agent.relay.publishers[arm].raw_command.put(text)
        return written_ns

    def _ack(self, arm: str, slot: ArmSlot) -> m.StopAck | None:
        stop = slot.safety.stop
        if stop is None:
            return None
        return m.StopAck(
            arm=arm,
            stop_id=stop.stop_id,
            action=slot.tracker.config.stop_action,
            received_ns=stop.received_ns,
            dds_written_ns=stop.dds_written_ns,
            still_ns=stop.still_ns,
        )

    def reset(self, arm: str, source: str) -> None:
        """Release the latch; the measured pose becomes the target, so nothing moves."""
        now, now_ns = time.monotonic(), time.time_ns()
        with self.agent.lock:
            slot = self.agent.slots[arm]
            released = slot.safety.reset()
            if released is None:
                return
            slot.tracker.estopped = False
            slot.safety.last_reason = f"reset by {source}"
            text = self._stop_text_for_hold(slot)
            status = encode(slot.tracker.status(now, now_ns))
        self._write(arm, text)
        self.agent.flush(Outbox(puts=[(self.agent.relay.publishers[arm].status, status)]))
        log.warning("arm %s reset by %s", arm, source)

    def _stop_text_for_hold(self, slot: ArmSlot) -> str | None:
        command = stop_command("hold", slot.tracker.angles_deg)
        if command is None or slot.tracker.powered is False or slot.tracker.link != "ok":
            # No fresh pose: release the latch but write nothing (a stale pose would move it).
            return None
        seq = slot.seqs.allocate()
        slot.seqs.release(seq)
        return p.encode_command(command, seq)

    # ------------------------------------------------------------------ periodic

    def _tick(self) -> None:
        """Repeat unconfirmed stops; trip the watchdog of arms whose coordinator went silent."""
        now = time.monotonic()
        for arm, slot in self.agent.slots.items():
            with self.agent.lock:
                watched = slot.safety.watched_by
                expired = slot.safety.watchdog_expired(
                    None if watched is None else self.last_heartbeat_s.get(watched), now
                )
                resend = (
                    None
                    if expired
                    else (self._stop_text(slot, now) if slot.safety.needs_resend(now) else None)
                )
            if expired:
                silent = now - self.last_heartbeat_s.get(watched or "", now - 99.0)
                self.stop(
                    arm,
                    m.StopRequest(
                        stamp_ns=time.time_ns(),
                        source="watchdog",
                        stop_id=f"watchdog-{arm}-{time.time_ns()}",
                        reason=f"heartbeat of coordinator {watched!r} lost for {silent:.2f} s",
                    ),
                )
            elif resend is not None:
                self._write(arm, resend)

    def on_still(self, arm: str, slot: ArmSlot, out: Outbox) -> None:
        """Feedback showed a stopped arm still: acknowledge it (caller holds the lock)."""
        ack = self._ack(arm, slot)
        if ack is not None:
            out.puts.append((self.agent.relay.publishers[arm].stop_ack, encode(ack)))


__all__ = ["ErrorCode", "SafetyLoop", "stop_command"]
