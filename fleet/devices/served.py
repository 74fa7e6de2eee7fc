"""A kind that brings its own ``UnitServer`` (the D1 arm), as the agent core builds it.

A device kind brings a driver, served by the core's device server; a *served* kind brings its
whole side of the agent instead: ``ServedKind.build`` takes what the core shares
(``CoreServices``) and returns its ``KindSide``: the server, its units, its DDS readers and
writers on the core's one participant (``LinkPart``) and its Zenoh publishers on the core's
one session. The core lists these kinds in the registry (``fleet.devices.registry``) and
builds each the same way, so nothing in ``edge_agent/`` names one.

A ``LinkPart`` hands the core each reader with the callable that takes its samples, bound
once at start-up: the core's relay thread waits over every reader of every kind in one
WaitSet and calls it directly, with no lookup or hand-off per sample.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import zenoh

from fleet.devices.envelope import Principals
from fleet.devices.unit import Outbox, Unit, UnitServer
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.wire import messages as m
from fleet.wire.keys import KeySpace

if TYPE_CHECKING:  # the DDS side: imported by the processes that run it
    from fleet.origin.directory import WriterDirectory

OnStill = Callable[[str, Outbox], None]
"""A stopped unit was seen still: its ack (caller holds the agent's lock)."""
Flush = Callable[[Outbox], None]
"""Performs the puts and replies collected under the lock (called without it)."""
OwnCounts = Callable[[m.Diag], m.Diag]
"""A unit's diag with the agent's own counters."""
Schedule = Callable[[float, Callable[[], None]], "str | None"]
"""Runs a write at a monotonic time (the core's ``starts`` thread); why not, when it is full."""


@dataclass(frozen=True)
class CoreServices:
    """What the agent core shares with a served kind: its lock, guard and shutdown event, one
    write lock per robot, its DDS participant and writer directory, its Zenoh session and key
    space, the synchronized-start thread, the envelope's principals, the stop acks, the
    outbox flush and the agent's own counters."""

    lock: threading.Lock
    guard: ThreadGuard
    stopping: threading.Event
    write_lock: Callable[[str], threading.Lock]
    dds: tuple[Any, WriterDirectory]
    """The participant every kind's entities are created on, and who wrote a sample."""
    zenoh: tuple[zenoh.Session, KeySpace]
    schedule: Schedule
    principals: Principals
    on_still: OnStill
    flush: Flush
    own_counts: OwnCounts


class LinkPart(Protocol):
    """A kind's DDS readers and writers on the core's participant (created once, at start-up,
    on the core's thread)."""

    @property
    def readers(self) -> Sequence[tuple[Any, Callable[[], None]]]:
        """Each reader and what takes its samples (relay thread), in WaitSet order."""

    @property
    def write_failures(self) -> int:
        """DDS writes refused since start (the agent's diag)."""


class KindSide(Protocol):
    """A served kind's side of the agent, as ``ServedKind.build`` returns it."""

    @property
    def server(self) -> UnitServer:
        """Its units' server."""

    @property
    def units(self) -> Mapping[str, Unit]:
        """The units it serves, by id."""

    @property
    def link(self) -> LinkPart:
        """Its part of the core's DDS link."""

    def close(self) -> None:
        """Undeclare its Zenoh entities (after the core's tokens, before its session)."""


@dataclass(frozen=True)
class ServedKind:
    """One served kind: ``name`` (its key word, e.g. ``arm``) and ``build``, which takes the
    units the agent was asked to serve, keeps its own and builds its side on ``CoreServices``
    (at start-up, on the core's thread)."""

    name: str
    build: Callable[[Inventory, Sequence[str], CoreServices], KindSide]
