"""The one path that writes a D1 command to an arm.

Every sender (commands, stops and their repeats, resets, the watchdog, contact force limiting,
a failed thread, shutdown) writes through ``ArmWriter.write``. Writes of one arm are serialized
by that arm's write lock, and what to write is decided under the agent's lock *inside* it, at
the moment of writing (``compose``): so a motion checked before a stop latched can never be
written after the stop's own command, and a hold takes the pose of that moment.

The write locks are the core's, one per robot (``edge_agent/writelocks.py``): a device's driver
writes under its own the same way. Lock order: an arm's write lock, then the agent's lock
(briefly, to compose). The agent's lock is never held across the DDS write or a Zenoh put; the
write lock is held across the DDS write (that is its job) but never across a Zenoh put.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from fleet.d1 import protocol as p
from fleet.d1arm.slot import ArmSlot

Compose = Callable[[ArmSlot, float], "tuple[p.Command, int] | None"]
"""Called with the arm's slot and the monotonic time, under the agent's lock, just before the
write: returns (command, seq) to write now, or None to write nothing."""

Observer = Callable[[str, p.Command, float], None]
"""Told (arm, command, monotonic time) after each write, outside every lock."""


@dataclass(frozen=True)
class Written:
    """A command written to an arm: whether DDS took it, when, and the text."""

    ok: bool
    written_ns: int
    command: p.Command
    text: str


class ArmWriter:
    """Writes D1 commands to the agent's arms, one arm at a time each."""

    def __init__(
        self,
        lock: threading.Lock,
        slots: dict[str, ArmSlot],
        unit_lock: Callable[[str], threading.Lock],
        dds: tuple[Callable[[str, str], bool], Callable[[str, str], None]],
    ) -> None:
        self._lock = lock
        self._slots = slots
        self._unit_lock = unit_lock  # the core's write lock of each robot
        # the arm's DDS command writer, and raw/command: what was written, for recorders
        self._dds_write, self._mirror = dds
        self.observers: list[Observer] = []

    def write(
        self, arm: str, compose: Compose, later: list[Callable[[], None]] | None = None
    ) -> Written | None:
        """Compose and write one command to ``arm``; None if ``compose`` chose nothing. With
        ``later``, the Zenoh mirror and the observers are appended there for the caller to run
        (a stop writes every arm's command to DDS before any Zenoh traffic)."""
        with self._unit_lock(arm):
            now = time.monotonic()
            with self._lock:
                slot = self._slots[arm]
                chosen = compose(slot, now)
                if chosen is not None:
                    # before the write: the ack may overtake it
                    slot.acks.written(chosen[1], now, chosen[0])
            if chosen is None:
                return None
            command, seq = chosen
            text = p.encode_command(command, seq, slot.tracker.config.joint_ranges_deg)
            ok = self._dds_write(arm, text)
            written = Written(ok, time.time_ns(), command, text)

        def tell() -> None:
            self._mirror(arm, text)
            for observer in self.observers:
                observer(arm, command, now)

        if later is None:
            tell()
        else:
            later.append(tell)
        return written


def transient_seq(slot: ArmSlot) -> int:
    """A seq for a command whose acks nobody awaits (a stop, a hold, a force limit): unique
    among the seqs in flight, and free again at once (caller holds the agent's lock)."""
    seq = slot.seqs.allocate()
    slot.seqs.release(seq)
    return seq
