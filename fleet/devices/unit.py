"""The one per-unit contract between the agent core and a robot kind's side of the agent.

Every robot the agent serves is a *unit*. The core keeps what every kind shares and acts on it
alike (``edge_agent/``: ``stops.py``, ``serving.py``, ``agent.py``): the latch, the lease and
the watchdog (``Unit.safety``), the command order (``Unit.order``). For what is a kind's own,
the core speaks to the unit's ``UnitServer`` and nothing else, keyed by the unit's id:

- what a stop does (safety thread): what a new latch ends (``latched``), its confirmation
  starting over (``started``), the stop action composed and written at the moment of writing
  under the robot's write lock (``write``), the status to put now (``status``), what a reset
  leaves behind (``released``);
- a command (commands thread): ``serve`` after the inbox, ``busy`` when the inbox was full
  (Zenoh thread: a reply only, nothing written to DDS);
- the periodic jobs (relay thread, ``tick``), its own threads (``threads``), and shutdown
  (``hold_if_moving``).

Two servers implement it: ``ArmServer`` (the D1 arms: ``fleet/d1arm/server.py``) and
``DeviceServer`` (every device kind through its driver: ``edge_agent/device_server.py``). The
contract sits below the kinds and the core, so a kind implements it without importing the core.

``Outbox`` holds the Zenoh puts and query replies computed under the agent's lock, performed
after it is released.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import zenoh

from fleet.devices.ordering import CommandOrder
from fleet.devices.safety import ArmSafety
from fleet.wire import messages as m
from fleet.wire.stoppath import TwoPathPublisher


def owner_of(principal: str, name: str) -> str:
    """A lease owner or heartbeat source: the authenticated ``principal``, then the name the
    payload gives (one principal may run several commanders: a player, a mirror, a CLI)."""
    return f"{principal}/{name}"


@dataclass(frozen=True)
class IncomingQuery:
    """A command query handed from a Zenoh thread to the agent's command thread.
    ``principal``: from the query's key (None: the key named none)."""

    arm: str
    query: zenoh.Query
    payload: bytes
    principal: str | None = None


Later = list[Callable[[], None]]
"""Zenoh traffic and observers a stop runs after every unit's DDS write."""


@dataclass
class Outbox:
    """I/O collected under the lock, performed after it is released."""

    puts: list[tuple[zenoh.Publisher | TwoPathPublisher, bytes | str]] = field(default_factory=list)
    replies: list[tuple[zenoh.Query, m.CommandReply]] = field(default_factory=list)


class Unit(Protocol):
    """The core's safety state of one robot, the same for every kind."""

    @property
    def safety(self) -> ArmSafety:
        """Its stop latch, lease and watchdog."""

    @property
    def order(self) -> CommandOrder:
        """At most once, never out of order, never past a command's lifetime."""

    @property
    def stop_action(self) -> str:
        """What its stop writes (the ack names it)."""


class UnitServer(Protocol):
    """A kind's side of the agent for its units (see the module docstring)."""

    threads: list[threading.Thread]
    """Threads of its own, started and joined with the agent's."""

    def latched(self, unit: str, now: float, out: Outbox) -> None:
        """A new stop latched (caller holds the agent's lock): end what it ends."""

    def started(self, unit: str, now: float) -> None:
        """After the lock, before the first write: the stop's confirmation starts over."""

    def write(self, unit: str, stop_id: str | None, later: Later | None) -> bool:
        """Write the action of the stop latched on ``unit`` (``stop_id``; None: whichever is
        latched) at the moment of writing; True if it is this stop's first write."""

    def status(self, unit: str, now: float, now_ns: int) -> tuple[zenoh.Publisher, bytes] | None:
        """The status to put now (caller holds the lock), or None (a device's next put)."""

    def released(self, unit: str, now: float, now_ns: int) -> None:
        """After a reset released the latch (no lock held)."""

    def serve(self, item: IncomingQuery, now: float) -> None:
        """One command of ``item.arm`` (commands thread): check, write, reply."""

    def busy(self, item: IncomingQuery, why: str) -> None:
        """Refuse ``item`` 4003 busy: the inbox could not queue it (Zenoh thread)."""

    def tick(self, now: float, stamp_ns: int, periodic: bool, diag: bool, out: Outbox) -> None:
        """The periodic jobs of its units (relay thread, no lock held): status when
        ``periodic``, diag when ``diag``, deadlines."""

    def hold_if_moving(self, unit: str) -> bool:
        """At shutdown: keep ``unit`` where it is if it still moves; True if a hold was
        written."""
