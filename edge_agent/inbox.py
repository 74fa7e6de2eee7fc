"""What the agent's Zenoh callbacks hand to its threads: bounded, decoded, stops first.

Safety (``SafetyInbox``): stops and resets go into one bounded FIFO, in arrival order (a reset
must not overtake the stop put before it, nor a stop the reset), which the ``safety`` thread
empties before it looks at heartbeats. Heartbeats are latest-wins per source: a flood of them
neither delays a stop nor grows memory. A stop payload that does not decode still stops (anyone
may stop anyway); a stop that finds the FIFO full is not dropped either: its target is marked,
and the safety thread latches it ("flood").

Commands (``CommandInbox``): a bounded FIFO of queries for the ``commands`` thread; a query that
finds it full is answered 4003 "busy" at once, from the queryable's callback (replying there is
how Zenoh's own examples serve queries), so the caller learns that the agent is overloaded
instead of waiting for a timeout, and nothing is queued without bound.

Callbacks run on Zenoh threads: they decode (size-capped, through ``fleet.wire.payloads``),
append under a short lock and signal; besides that busy reply they never call Zenoh.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import zenoh

from fleet.beat_limits import BeatGate, max_heartbeat_bytes
from fleet.control import CONTROL_DEPTH, ControlFifo
from fleet.devices.unit import IncomingQuery, owner_of
from fleet.wire import messages as m
from fleet.wire import payloads

MAX_BEAT_SOURCES = 64
"""Distinct heartbeat sources kept between two safety ticks (50 ms); sources that watch an
arm are always kept."""
COMMAND_DEPTH = 256
"""Commands waiting for the commands thread; one more is answered 4003 "busy"."""


@dataclass(frozen=True)
class StopEvent:
    """A stop for ``arm`` (None: every arm of the agent). ``request`` is None when the payload
    did not decode or the FIFO was full; ``why`` then says which."""

    arm: str | None
    request: m.StopRequest | None
    why: str = ""


@dataclass(frozen=True)
class ResetEvent:
    """A reset of ``arm`` (None: every arm of the agent)."""

    arm: str | None
    request: m.ResetRequest


ControlEvent = StopEvent | ResetEvent


@dataclass
class InboxCounters:
    """What the callbacks refused or dropped (published in every arm's ``diag``)."""

    bad_payloads: int = 0
    undecodable_stops: int = 0
    dropped_events: int = 0
    busy: int = 0
    bad_stamps: int = 0
    """Stops and resets stamped far ahead of this host's clock (``STAMP_AHEAD_LIMIT_S``)."""
    bad_keys: int = 0
    """Command queries (refused by the unit's server) and heartbeats (ignored) on a key naming
    no usable principal."""
    stop_copies: dict[bool, int] = field(default_factory=lambda: {False: 0, True: 0})
    """Stop copies received, per path (True: the datagram path)."""
    beat_copies: dict[bool, int] = field(default_factory=lambda: {False: 0, True: 0})
    """Heartbeat copies received, per path (True: the datagram path)."""


class SafetyInbox:
    """Stops and resets (one ordered FIFO) and heartbeats (latest per source)."""

    def __init__(
        self, counters: InboxCounters, max_beat_bytes: int = max_heartbeat_bytes(1)
    ) -> None:
        self.counters = counters
        self.max_beat_bytes = max_beat_bytes
        """Longer heartbeats are dropped unread (the fleet's bound: ``max_heartbeat_bytes``)."""
        self._gate = BeatGate()  # guarded by _lock
        self.wake = threading.Event()
        self._lock = threading.Lock()  # guards the counters, the beats
        # stops and resets: the fleet's one ordered intake (fleet.control)
        self._control: ControlFifo[ControlEvent] = ControlFifo(
            lambda arm: StopEvent(arm, None, "stop request dropped at a full queue (flood)"),
            CONTROL_DEPTH,
        )
        self._beats: dict[str, tuple[str, m.Heartbeat, float]] = {}
        self._keep: frozenset[str] = frozenset()

    def depth(self) -> int:
        """Stops and resets waiting for the safety thread (metrics)."""
        return len(self._control)

    def on_stop(self, arm: str | None, data: bytes, datagram: bool = False) -> None:
        """A sample on ``estop`` or ``arm/<arm>/estop`` (Zenoh thread); ``datagram``: its copy
        on the datagram path."""
        with self._lock:
            self.counters.stop_copies[datagram] += 1
        try:
            event = StopEvent(arm, payloads.STOP.decode(data))
        except payloads.PayloadError as exc:
            event = StopEvent(arm, None, f"undecodable stop request ({exc.why[:200]})")
            with self._lock:
                self.counters.bad_payloads += 1
                self.counters.undecodable_stops += 1
        self._control.push(event, arm, is_stop=True)  # bounded marks: the agent's arms, None
        self.wake.set()

    def on_reset(self, arm: str | None, data: bytes) -> None:
        """A sample on ``reset`` or ``arm/<arm>/reset`` (Zenoh thread). An undecodable or
        dropped reset releases nothing: failing safe keeps the latch."""
        try:
            event = ResetEvent(arm, payloads.RESET.decode(data))
        except payloads.PayloadError:
            with self._lock:
                self.counters.bad_payloads += 1
            return
        if not self._control.push(event):
            with self._lock:
                self.counters.dropped_events += 1
            return
        self.wake.set()

    def on_heartbeat(
        self, principal: str | None, data: bytes | zenoh.ZBytes, datagram: bool = False
    ) -> m.Heartbeat | None:
        """A sample on ``heartbeat/<principal>`` (Zenoh thread): keep the newest per source, and
        return it (None: refused). The source is ``<principal>/<coordinator>``: the principal
        comes from the key (the router lets only it publish there), the payload only names one
        of its commanders.
        Bounded before it is copied or parsed (``fleet.beat_limits``): its size, then a rate
        per principal; what does not pass is counted in ``dropped_events``."""
        arrived = time.monotonic()
        with self._lock:
            self.counters.beat_copies[datagram] += 1
            refused = len(data) > self.max_beat_bytes or not self._gate.admit(principal or "")
            if refused:
                self.counters.dropped_events += 1
        if refused:
            return None
        if principal is None:  # heartbeat/bob.smith: no principal the watchdog could watch
            with self._lock:
                self.counters.bad_keys += 1
            return None
        try:
            beat = payloads.HEARTBEAT.decode(data if isinstance(data, bytes) else data.to_bytes())
        except payloads.PayloadError:
            with self._lock:
                self.counters.bad_payloads += 1
            return None
        with self._lock:
            source = owner_of(principal, beat.coordinator)
            if (
                source not in self._beats
                and len(self._beats) >= MAX_BEAT_SOURCES
                and source not in self._keep
            ):
                self.counters.dropped_events += 1
                return None
            self._beats[source] = (source, beat, arrived)
        return beat

    def count_bad_stamp(self) -> None:
        """A stop or reset stamped far ahead of this host's clock (the safety thread's)."""
        with self._lock:
            self.counters.bad_stamps += 1

    def keep_sources(self, sources: frozenset[str]) -> None:
        """Sources whose heartbeats are never dropped (they watch an arm)."""
        self._keep = sources

    def take(self) -> tuple[list[ControlEvent], list[tuple[str, m.Heartbeat, float]]]:
        """Everything pending: stops and resets in arrival order (then the stops that found
        the FIFO full), and the newest heartbeat of each source (source, beat, arrival)."""
        control = self._control.take()
        with self._lock:
            beats = list(self._beats.values())
            self._beats.clear()
        return control, beats


class CommandInbox:
    """Command queries for the commands thread; ``busy`` answers those it cannot queue."""

    def __init__(
        self,
        counters: InboxCounters,
        busy: Callable[[IncomingQuery], None],
        principal_of: Callable[[object], str | None],
    ) -> None:
        self.counters = counters
        self._principal_of = principal_of
        self.wake = threading.Event()
        self._busy = busy
        self._lock = threading.Lock()
        self._queries: deque[IncomingQuery] = deque()

    def depth(self) -> int:
        """Commands waiting for the commands thread (metrics)."""
        return len(self._queries)

    def on_query(self, arm: str, query: zenoh.Query) -> None:
        """A query on ``arm/<arm>/cmd`` (Zenoh thread)."""
        payload = query.payload.to_bytes() if query.payload is not None else b""
        item = IncomingQuery(arm, query, payload, self._principal_of(query.key_expr))
        with self._lock:
            if item.principal is None:
                self.counters.bad_keys += 1  # the unit's server refuses it, with the reason
            queued = len(self._queries) < COMMAND_DEPTH
            if queued:
                self._queries.append(item)
            else:
                self.counters.busy += 1
        if queued:
            self.wake.set()
        else:
            self._busy(item)

    def take(self) -> IncomingQuery | None:
        """The oldest query waiting to be served, or None."""
        with self._lock:
            if self._queries:
                return self._queries.popleft()
            self.wake.clear()
            return None
