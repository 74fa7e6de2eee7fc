"""The D1 arms' side of the agent: how a stop acts on an arm, its feedback and periodic jobs,
its commands (``serving.py``) and its shutdown hold.

A stop on an arm: a latch fails its commands in flight; the action (hold of the fresh measured
pose, unload, power off) is composed from the tracker by the arm writer at the moment of
writing; the status is put at once; a reset makes the fresh measured pose the target. Its
confirmation comes from feedback (``on_feedback``: standstill, or a reported unload / power
off), on the relay thread.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping

import zenoh

from fleet.d1 import protocol as p
from fleet.d1arm.contact_edge import ContactEdge
from fleet.d1arm.holds import NO_FRESH_POSE, hold_command, stop_command
from fleet.d1arm.publishers import ArmPublishers
from fleet.d1arm.serving import ArmCommands
from fleet.d1arm.slot import ArmSlot
from fleet.d1arm.writer import ArmWriter, transient_seq
from fleet.devices.served import Flush, OnStill, OwnCounts
from fleet.devices.unit import IncomingQuery, Later, Outbox
from fleet.files import FILE_TIMEOUT_S, FileWatcher
from fleet.guard import ThreadGuard
from fleet.origin.trust import SampleWriter
from fleet.wire import messages as m
from fleet.wire.messages import encode

log = logging.getLogger("edge_agent")

CALIBRATION_POLL_S = 1.0
"""How often the ``files`` thread looks for a new calibration file (``fleet calibrate``)."""


class ArmServer:
    """Every D1 arm of the agent."""

    def __init__(
        self,
        lock: threading.Lock,
        slots: dict[str, ArmSlot],
        io: tuple[ArmWriter, Mapping[str, ArmPublishers], ContactEdge, ArmCommands],
        hooks: tuple[OnStill, Flush, OwnCounts],
        guard: ThreadGuard,
        stopping: threading.Event,
    ) -> None:
        self._lock = lock
        self.slots = slots
        self._writer, self._publishers, self.contact, self._commands = io
        self._on_still, self._flush, self._own_counts = hooks
        self._guard = guard
        self._writer.observers.append(self._on_written)
        # Files are read on a thread of their own (fleet.files): never on the relay's.
        self.calibrations = FileWatcher(
            self.contact.read_calibrations, CALIBRATION_POLL_S, stopping
        )
        self.threads = [guard.thread(self.calibrations.run, "files")]

    # ------------------------------------------------------------------ stops

    def latched(self, unit: str, now: float, out: Outbox) -> None:
        self.slots[unit].cancel_in_flight(now, "a protective stop was latched", out)

    def started(self, unit: str, now: float) -> None:
        """The arm's standstill was cleared by the latch itself."""

    def write(self, unit: str, stop_id: str | None, later: Later | None) -> bool:
        def compose(slot: ArmSlot, now: float) -> tuple[p.Command, int] | None:
            stop = slot.safety.stop
            if stop is None or (stop_id is not None and stop.stop_id != stop_id):
                return None  # reset meanwhile, or superseded (the newer stop writes its own)
            stop.last_sent_s = now
            command = stop_command(slot.tracker.config.stop_action, slot.tracker, now)
            stop.detail = NO_FRESH_POSE if command is None else None
            return None if command is None else (command, transient_seq(slot))

        written = self._writer.write(unit, compose, later)
        if written is None or not written.ok:
            return False
        with self._lock:
            stop = self.slots[unit].safety.stop
            if stop is not None and stop.dds_written_ns is None:
                stop.dds_written_ns = written.written_ns
                return True
        return False

    def status(self, unit: str, now: float, now_ns: int) -> tuple[zenoh.Publisher, bytes] | None:
        tracker = self.slots[unit].tracker
        return self._publishers[unit].status, encode(tracker.status(now, now_ns))

    def released(self, unit: str, now: float, now_ns: int) -> None:
        """The fresh measured pose becomes the target, so nothing moves."""
        with self._lock:
            status = self.status(unit, now, now_ns)

        def hold_unless_off(slot: ArmSlot, now: float) -> tuple[p.Command, int] | None:
            if slot.safety.latched or slot.tracker.powered is False:
                return None  # stopped again meanwhile, or nothing to hold
            command = hold_command(slot.tracker, now)  # None without a fresh pose
            return None if command is None else (command, transient_seq(slot))

        self._writer.write(unit, hold_unless_off)
        self._flush(Outbox(puts=[status] if status is not None else []))

    # ------------------------------------------------------------------ commands

    def serve(self, item: IncomingQuery, now: float) -> None:
        self._commands.serve(item, now)

    def busy(self, item: IncomingQuery, why: str) -> None:
        self._commands.busy(item, why)

    # ------------------------------------------------------------------ the relay thread

    def on_feedback(
        self, arm: str, text: bytes, now: float, writer: SampleWriter | None = None
    ) -> None:
        """One feedback sample of ``arm``: decode, track, relay, confirm its stop."""
        stamp_ns = time.time_ns()
        pubs = self._publishers[arm]
        out = Outbox()
        with self._lock:
            slot = self.slots[arm]
            tracker = slot.tracker
            error_status = tracker.error_status
            decoded = tracker.on_feedback(text, now, writer)
            status_changed = tracker.update_link(now)
            if decoded is not None:
                message = decoded.message
                if isinstance(message, p.JointAngles):
                    slot.joints_seq += 1
                    joints = m.Joints(stamp_ns, list(message.angles_deg), slot.joints_seq)
                    out.puts.append((pubs.joints, encode(joints)))  # before the raw string
                    for flight, _query in slot.in_flight.values():
                        flight.on_angles(message.angles_deg)
                    if slot.safety.on_angles(message.angles_deg, stamp_ns, now):
                        self._on_still(arm, out)
                elif isinstance(message, p.D1Status):
                    status_changed = True
                    if message.error_status != error_status:  # logged on change only
                        _log_error_status(arm, message.error_status)
                    if slot.safety.on_status(message.enabled, message.powered, stamp_ns):
                        self._on_still(arm, out)  # acknowledged as confirmed
                elif isinstance(message, (p.ReceiveAck, p.ExecuteAck)):
                    slot.on_ack(message, now)
                else:
                    status_changed = True
            if pubs.raw_feedback_matched and len(text) <= p.MAX_MESSAGE_BYTES:
                out.puts.append((pubs.raw_feedback, text))  # for debugging, not for floods
            if status_changed:
                out.puts.append((pubs.status, encode(tracker.status(now, stamp_ns))))
            if decoded is not None:
                self.contact.on_message(arm, slot, decoded.message, now, stamp_ns, out)
            slot.collect_finished(now, out)
        self._flush(out)
        self.contact.flush()  # force-limit writes, after the lock

    def on_bad_sample(self, arm: str, why: str) -> None:
        """A sample on the arm's feedback topic that is not an ArmString_: counted."""
        with self._lock:
            tracker = self.slots[arm].tracker
            tracker.malformed += 1
            tracker.last_error = f"malformed feedback: {why}"

    def _on_written(self, arm: str, command: p.Command, now: float) -> None:
        """Watch the pose after an enable of all joints; a motion ends the watch (called
        without the lock, after the write)."""
        with self._lock:
            tracker = self.slots[arm].tracker
            if isinstance(command, p.SetAllTorque) and command.mode > 0:
                setting = f"funcode 5 mode {command.mode}, enable_mode {tracker.config.enable_mode}"
                tracker.sag.armed(tracker.angles_deg, now, setting)
            elif isinstance(command, (p.SetJointAngle, p.ReturnToZero)) or (
                isinstance(command, p.SetAllAngles) and command.angles_deg != tracker.angles_deg
            ):
                tracker.sag.cancel()

    def tick(self, now: float, stamp_ns: int, periodic: bool, diag: bool, out: Outbox) -> None:
        """Link state, command deadlines, status (``periodic``), diag and calibrations
        (``diag``)."""
        if diag:
            self.contact.apply_calibrations(self.calibrations.take(), self.slots)
            stuck_s = self.calibrations.stuck_s(now)
            if stuck_s > FILE_TIMEOUT_S:  # a hung read: latch every arm and exit (the guard)
                why = f"reading a calibration file has taken {stuck_s:.0f} s"
                self._guard.fail("files", TimeoutError(why))
        with self._lock:
            for arm, slot in self.slots.items():
                tracker = slot.tracker
                pubs = self._publishers[arm]
                if tracker.update_link(now) or periodic:
                    out.puts.append((pubs.status, encode(tracker.status(now, stamp_ns))))
                if diag:
                    arm_diag = self._own_counts(tracker.diag(now, stamp_ns))
                    out.puts.append((pubs.diag, encode(arm_diag)))
                for flight, _query in list(slot.in_flight.values()):
                    flight.on_time(now, tracker.angles_deg)
                slot.collect_finished(now, out)

    # ------------------------------------------------------------------ shutdown

    def hold_if_moving(self, unit: str) -> bool:
        def hold_if_moving(slot: ArmSlot, now: float) -> tuple[p.Command, int] | None:
            tracker = slot.tracker
            if slot.safety.standstill.still or slot.safety.latched or tracker.powered is False:
                return None  # still, or already held by its stop
            command = hold_command(tracker, now)  # None without a fresh pose
            return None if command is None else (command, transient_seq(slot))

        if self._writer.write(unit, hold_if_moving) is None:
            return False
        log.info("arm %s was moving: held it before shutting down", unit)
        return True


def _log_error_status(arm: str, error_status: int) -> None:
    """The arm's ``error_status`` changed: the raw value, which may be a bitfield of faults."""
    if error_status == p.ERROR_STATUS_NORMAL:
        log.info("arm %s: error_status %d (normal)", arm, error_status)
    else:
        log.warning(
            "arm %s: error_status %d (abnormal; 0x%x as a bitfield)",
            arm,
            error_status,
            error_status & (2**64 - 1),
        )
