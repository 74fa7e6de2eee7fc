"""Contact detection at the edge: feeds each arm's detector, publishes contact events, and
limits force by position.

The agent calls two hooks: ``on_message`` (under the agent's lock, for every decoded feedback
message) and ``flush`` (after the lock is released: the force-limit writes); the arm writer
tells ``on_sent`` every command it wrote (it takes the lock itself). Nothing here
blocks or does I/O under the lock: events go into the agent's outbox, DDS writes into
``_pending`` until ``flush``.

Force limiting by position (the D1 has no torque limit): when a contact confirmed by a method
trustworthy for this arm (never an uncalibrated or untrusted model) has a tracking
error past ``force_limit_deg``, the joint's target becomes its measured angle (``1/1``), so the
motor stops pushing; commands in flight that move that joint fail with 4002 (refused).

Calibration: each arm's file (``Inventory.calibration_path``) is read at start and again when it
changes (``read_calibrations``, on the agent's ``files`` thread: never on the relay or safety
path, see ``fleet.files``), then applied on the relay thread (``apply_calibrations``):
``fleet calibrate`` takes effect without a restart. The model's state goes into the arm's
status and diag.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import zenoh

from fleet.contact.calibration import Calibration, CalibrationError, load_calibration
from fleet.contact.detector import ContactChange, ContactDetector
from fleet.contact.feed import feed_command
from fleet.d1 import protocol as p
from fleet.d1.limits import JOINT_COUNT
from fleet.d1arm.slot import ArmSlot
from fleet.d1arm.writer import ArmWriter, transient_seq
from fleet.devices.unit import Outbox
from fleet.files import file_stamp
from fleet.inventory import ArmConfig
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.keys import KeySpace
from fleet.wire.messages import ErrorCode, encode

log = logging.getLogger("edge_agent.contact")


def contact_event(change: ContactChange, stamp_ns: int, force_limited: bool) -> m.ContactEvent:
    """The key-space payload of one detector state change."""
    return m.ContactEvent(
        stamp_ns=stamp_ns,
        joint=change.joint,
        state=change.state.value,
        method=change.method,
        error_deg=change.error_deg,
        confidence=change.confidence,
        target_deg=change.target_deg,
        measured_deg=change.measured_deg,
        commanded=change.commanded,
        grip=change.grip,
        force_limited=force_limited,
    )


class ContactEdge:
    """One detector per arm of the agent (arms whose inventory disables contact get none)."""

    def __init__(
        self,
        configs: dict[str, ArmConfig],
        zenoh_side: tuple[zenoh.Session, KeySpace],
        lock: threading.Lock,
        writer: ArmWriter,
        calibrations: dict[str, Path] | None = None,
    ) -> None:
        self._lock = lock
        self._writer = writer
        session, space = zenoh_side  # the agent's session and key space
        self._paths = calibrations or {}
        self._stamps: dict[str, tuple[float, int, int] | None] = {}  # files thread only
        self._problems: dict[str, str] = {}  # guarded by lock
        # The wire joints a loaded calibration lacks (fleet calibrate --joint J calibrates one):
        # such an arm's model is "partial", not "calibrated" (guarded by lock).
        self._missing: dict[str, tuple[int, ...]] = {}
        self.detectors: dict[str, ContactDetector] = {}
        self.publishers: dict[str, zenoh.Publisher] = {}
        for arm, arm_config in configs.items():
            config = arm_config.contact
            if not config.enabled:
                continue
            self.detectors[arm] = ContactDetector(
                config, gripper_closing_sign=arm_config.gripper_closing_sign
            )
            # Events must arrive: BLOCK, like status (a contact is rare and small).
            self.publishers[arm] = session.declare_publisher(
                space.arm(arm, keys.CONTACT),
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.BLOCK,
                priority=zenoh.Priority.DATA_HIGH,
            )
        self._pending: list[tuple[str, p.SetJointAngle]] = []  # guarded by lock
        writer.observers.append(self.on_sent)

    def read_calibrations(self) -> dict[str, tuple[Calibration | None, str | None]] | None:
        """Each arm's calibration file that appeared or changed, read (bounded: a regular file,
        size-capped) and validated: arm -> (calibration or None, problem or None); None when
        nothing changed. Runs on the agent's ``files`` thread, never on the relay's: a file
        that blocks can freeze only that thread, which the relay's tick then fails safe."""
        loaded: dict[str, tuple[Calibration | None, str | None]] = {}
        for arm in self.detectors:
            path = self._paths.get(arm)
            stamp = file_stamp(path)
            if arm in self._stamps and self._stamps[arm] == stamp:
                continue
            self._stamps[arm] = stamp
            try:
                calibration = None if path is None or stamp is None else load_calibration(path)
                loaded[arm] = (calibration, None)
            except CalibrationError as exc:
                loaded[arm] = (None, str(exc))
                log.error("arm %s: %s", arm, exc)
                continue
            if calibration is not None:
                log.info("arm %s: contact model calibrated from %s", arm, path)
        return loaded or None

    def apply_calibrations(
        self,
        loaded: dict[str, tuple[Calibration | None, str | None]] | None,
        slots: dict[str, ArmSlot],
    ) -> None:
        """Hand what ``read_calibrations`` read to the detectors, and each detector's model
        state to its arm's tracker (relay thread; takes the lock; reads no file)."""
        with self._lock:
            for arm, (calibration, problem) in (loaded or {}).items():
                self.detectors[arm].set_calibration(calibration)
                self._missing[arm] = (
                    ()
                    if calibration is None
                    else tuple(j for j in range(JOINT_COUNT) if calibration.joint(j) is None)
                )
                if problem is None:
                    self._problems.pop(arm, None)
                else:
                    self._problems[arm] = problem
            for arm, detector in self.detectors.items():
                self._tell(arm, slots[arm], detector)

    def _tell(self, arm: str, slot: ArmSlot, detector: ContactDetector) -> None:
        """The detector's model state into the arm's tracker (caller holds the lock)."""
        sanity = detector.sanity
        tracker = slot.tracker
        missing = self._missing.get(arm, ())
        tracker.contact_model = (
            "uncalibrated"
            if not sanity.calibrated
            else "untrusted"
            if not sanity.trusted
            else "partial"
            if missing
            else "calibrated"
        )
        note = sanity.note()
        if sanity.calibrated and missing:
            joints = " ".join(f"j{j}" for j in missing)
            note += f"; joints {joints} not calibrated (fleet calibrate {arm})"
        problem = self._problems.get(arm)
        tracker.contact_note = note if problem is None else f"{note}; {problem}"
        tracker.contact_free_moves = sanity.free_moves
        tracker.contact_model_error_deg = sanity.last_error_deg

    def on_message(
        self,
        arm: str,
        slot: ArmSlot,
        message: p.ArmMessage,
        now: float,
        stamp_ns: int,
        out: Outbox,
    ) -> None:
        """Feed one decoded feedback message (caller holds the agent's lock)."""
        detector = self.detectors.get(arm)
        if detector is None:
            return
        if isinstance(message, p.D1Status):
            detector.on_status(message.error, message.enabled, message.powered, now)
            return
        if not isinstance(message, p.JointAngles):
            return
        tracker = slot.tracker
        if tracker.estopped:
            if tracker.config.stop_action == "hold":  # the stop holds the measured pose
                detector.on_targets(dict(enumerate(message.angles_deg)), 0, now)
            else:
                detector.set_tracking(False)  # unload / power off: the arm does not track
        report = detector.on_angles(message.angles_deg, now)
        if report.model_note is not None:
            log.warning("arm %s: contact detector: %s", arm, report.model_note)
            self._tell(arm, slot, detector)
        limited = set()
        if not tracker.estopped:
            for joint, angle in report.force_limit.items():
                self._limit(arm, slot, joint, angle)
                limited.add(joint)
        for change in report.changes:
            event = contact_event(change, stamp_ns, change.joint in limited)
            out.puts.append((self.publishers[arm], encode(event)))
            log.info(
                "arm %s joint %d %s (%s)", arm, change.joint, change.state.value, change.method
            )

    def _limit(self, arm: str, slot: ArmSlot, joint: int, angle: float) -> None:
        """Retract ``joint``'s target to ``angle`` (caller holds the lock)."""
        lo, hi = slot.tracker.config.joint_ranges_deg[joint]
        self._pending.append((arm, p.SetJointAngle(joint, round(min(max(angle, lo), hi), 2))))
        why = f"contact on joint {joint}: target retracted to {angle:.1f} deg (force limit)"
        for flight, _query in slot.in_flight.values():
            if joint in flight.targets_deg:
                flight.fail(ErrorCode.REJECTED, why)
        log.warning("arm %s: %s", arm, why)

    def flush(self) -> None:
        """Write the force-limit commands collected under the lock (call without the lock);
        like a stop, each is confirmed by feedback, not by acks, and none is written once a
        stop latched (the stop's own command holds the arm)."""
        with self._lock:
            pending, self._pending = self._pending, []
        for arm, command in pending:

            def compose(
                slot: ArmSlot, _now: float, command: p.SetJointAngle = command
            ) -> tuple[p.Command, int] | None:
                return None if slot.safety.latched else (command, transient_seq(slot))

            self._writer.write(arm, compose)

    def on_sent(self, arm: str, command: p.Command, now: float) -> None:
        """The writer wrote ``command`` to ``arm`` (called without the lock)."""
        detector = self.detectors.get(arm)
        if detector is None:
            return
        with self._lock:
            feed_command(detector, command, now)
