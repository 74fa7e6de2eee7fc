"""How a stop acts on one robot, by kind. The safety loop (``stops.py``) decides *when* for
every kind alike: the latch, its repeats until confirmed, the acks, the watchdog, the reset. A
unit's ``UnitStops`` says *how*: what a new latch ends, how the stop action is written (composed
at the moment of writing, under the robot's write lock), what status to publish, and what a
reset leaves behind.

- ``ArmStops``: a D1 arm. A latch fails its commands in flight; the action (hold of the fresh
  measured pose, unload, power off) is composed from the tracker by the arm writer; the status
  is put at once; a reset makes the fresh measured pose the target.
- ``DeviceStops``: a device of another kind. Its driver writes its kind's action
  (``DeviceDriver.write_stop``) and tells when its state confirms it; its state payload carries
  the latch at its next put; a reset moves nothing.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol

import zenoh

from edge_agent.holds import NO_FRESH_POSE, hold_command, stop_command
from edge_agent.relay import ZenohRelay
from edge_agent.slots import ArmSlot, DeviceSlot, Outbox, Unit
from edge_agent.writer import ArmWriter, transient_seq
from fleet.d1 import protocol as p
from fleet.wire.messages import encode

CancelInFlight = Callable[[ArmSlot, float, str, Outbox], None]
Later = list[Callable[[], None]]


class UnitStops(Protocol):
    """How a stop acts on one kind of robot (see the module docstring)."""

    def latched(self, slot: Unit, now: float, out: Outbox) -> None:
        """A new stop latched (caller holds the agent's lock): end what it ends."""

    def started(self, slot: Unit, now: float) -> None:
        """After the lock, before the first write: the stop's confirmation starts over."""

    def write(self, unit: str, stop_id: str | None, later: Later | None) -> bool:
        """Write the action of the stop latched on ``unit`` (``stop_id``; None: whichever is
        latched) at the moment of writing; True if it is this stop's first write."""

    def status(
        self, unit: str, slot: Unit, now: float, now_ns: int
    ) -> tuple[zenoh.Publisher, bytes] | None:
        """The status to put now (caller holds the lock), or None (a device's next put)."""

    def released(self, unit: str, slot: Unit, now: float, now_ns: int) -> None:
        """After a reset released the latch (no lock held)."""


class ArmStops:
    """A D1 arm's stop: through the arm writer, from the tracker."""

    def __init__(
        self,
        lock: threading.Lock,
        slots: dict[str, ArmSlot],
        writer: ArmWriter,
        relay: ZenohRelay,
        hooks: tuple[CancelInFlight, Callable[[Outbox], None]],
    ) -> None:
        self._lock = lock
        self._slots = slots
        self._writer = writer
        self._relay = relay
        self._cancel_in_flight, self._flush = hooks

    def latched(self, slot: Unit, now: float, out: Outbox) -> None:
        assert isinstance(slot, ArmSlot)
        self._cancel_in_flight(slot, now, "a protective stop was latched", out)

    def started(self, slot: Unit, now: float) -> None:
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
            stop = self._slots[unit].safety.stop
            if stop is not None and stop.dds_written_ns is None:
                stop.dds_written_ns = written.written_ns
                return True
        return False

    def status(
        self, unit: str, slot: Unit, now: float, now_ns: int
    ) -> tuple[zenoh.Publisher, bytes] | None:
        assert isinstance(slot, ArmSlot)
        return self._relay.publishers[unit].status, encode(slot.tracker.status(now, now_ns))

    def released(self, unit: str, slot: Unit, now: float, now_ns: int) -> None:
        """The fresh measured pose becomes the target, so nothing moves."""
        assert isinstance(slot, ArmSlot)
        with self._lock:
            status = self.status(unit, slot, now, now_ns)

        def hold_unless_off(slot: ArmSlot, now: float) -> tuple[p.Command, int] | None:
            if slot.safety.latched or slot.tracker.powered is False:
                return None  # stopped again meanwhile, or nothing to hold
            command = hold_command(slot.tracker, now)  # None without a fresh pose
            return None if command is None else (command, transient_seq(slot))

        self._writer.write(unit, hold_unless_off)
        self._flush(Outbox(puts=[status] if status is not None else []))


class DeviceStops:
    """A device's stop: its driver writes its kind's action under the device's write lock."""

    def __init__(self, lock: threading.Lock, writer: ArmWriter, slots: dict[str, Unit]) -> None:
        self._lock = lock
        self._writer = writer
        self._slots = slots

    def latched(self, slot: Unit, now: float, out: Outbox) -> None:
        """Nothing in flight to end: a device's commands are written at once (a G1's RPC
        answer, if one comes, is only reported)."""

    def started(self, slot: Unit, now: float) -> None:
        assert isinstance(slot, DeviceSlot)
        slot.driver.stop_started(now)

    def write(self, unit: str, stop_id: str | None, later: Later | None) -> bool:
        slot = self._slots[unit]
        assert isinstance(slot, DeviceSlot)
        with self._writer.unit_lock(unit):
            now = time.monotonic()
            with self._lock:
                stop = slot.safety.stop
                if stop is None or (stop_id is not None and stop.stop_id != stop_id):
                    return False  # reset meanwhile, or superseded
                stop.last_sent_s = now
            written, detail = slot.driver.write_stop(now)
            with self._lock:
                stop.detail = detail
                if written and stop.dds_written_ns is None:
                    stop.dds_written_ns = time.time_ns()
                    return True
        return False

    def status(
        self, unit: str, slot: Unit, now: float, now_ns: int
    ) -> tuple[zenoh.Publisher, bytes] | None:
        return None  # the device's state says it at its next put

    def released(self, unit: str, slot: Unit, now: float, now_ns: int) -> None:
        """It stays as the stop left it."""
        assert isinstance(slot, DeviceSlot)
        slot.driver.stop_cleared()
