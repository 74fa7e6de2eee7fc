"""The viewer's event log: what an operator on shift needs to look back at, newest first.

Stops (who asked, why, and once every arm is still how long each took: the coordinator's
``estop/report``, slowest arm named), resets, contacts, refusals, agents going offline and
coming back, choreographies starting, completing or stopping (and why), each with its
wall-clock time. Events come from the key space (viewer/state.py
derives them from transitions, so a status repeated at 4 Hz is one event, not four a second)
and from the viewer itself (a jog refused). The log is bounded: a flapping agent or a hostile
flood of stop requests pushes old entries out, it never grows memory. Thread-safe: Zenoh
callbacks add, the render thread reads.
"""

from __future__ import annotations

import html
import threading
import time
from collections import OrderedDict, deque
from dataclasses import dataclass

from fleet.wire import messages as m

MAX_EVENTS = 200
"""Entries kept (oldest dropped first)."""
SHOWN_EVENTS = 40
"""Entries the panel shows (the newest)."""
MAX_STOP_IDS = 256
"""Stop ids remembered to log a stop once, not once per repeat (agents repeat each stop)."""
MAX_TEXT = 300
"""Characters of an event's text (a reason is operator text; a hostile one is cut)."""

STOP, RESET, CONTACT, REFUSED, OFFLINE, ONLINE, RELEASED = (
    "stop",
    "reset",
    "contact",
    "refused",
    "offline",
    "online",
    "released",
)
DANCE, DANCE_STOPPED = "dance", "dance stopped"
"""A choreography started or completed; one stopped before its end (viewer/dance.py)."""
KIND_COLOUR = {
    STOP: "#c0392b",
    RESET: "#2471a3",
    CONTACT: "#d68910",
    REFUSED: "#8e44ad",
    OFFLINE: "#555555",
    ONLINE: "#1e8449",
    RELEASED: "#1e8449",
    DANCE: "#1e8449",
    DANCE_STOPPED: "#c0392b",
}


def stop_timing_text(report: m.StopReport) -> str | None:
    """One stop's fan-out once every arm in its report was seen still: how long the slowest
    took from the stop's put, named, and the slowest receipt. None until then (an arm that
    never gets still, e.g. one unpowered, leaves only the stop's own entry)."""
    timings = report.arms
    if not timings or any(t.still_ms is None for t in timings.values()):
        return None
    slowest = max(timings, key=lambda arm: timings[arm].still_ms or 0.0)
    received = [t.received_ms for t in timings.values() if t.received_ms is not None]
    count = len(timings)
    text = (
        f"stop by {report.source}: {count} arm{'s' if count > 1 else ''} still within "
        f"{timings[slowest].still_ms:.0f} ms of the put (slowest {slowest})"
    )
    if received:
        text += f", received within {max(received):.0f} ms"
    return text


@dataclass(frozen=True)
class Event:
    """One entry: when (wall clock, ns), what kind, which arm (None: the fleet), what."""

    wall_ns: int
    kind: str
    arm: str | None
    text: str


class EventLog:
    """A bounded, thread-safe log; ``add`` from any thread, ``newest``/``html`` to read."""

    def __init__(self, limit: int = MAX_EVENTS) -> None:
        self._lock = threading.Lock()  # guards every attribute below
        self._events: deque[Event] = deque(maxlen=limit)
        self._stop_ids: OrderedDict[str, None] = OrderedDict()
        self.version = 0
        """Bumped on every add: the panel re-renders only when it changed."""

    def add(self, kind: str, arm: str | None, text: str, wall_ns: int | None = None) -> None:
        """Log one event (``wall_ns`` defaults to now)."""
        event = Event(wall_ns or time.time_ns(), kind, arm, text[:MAX_TEXT])
        with self._lock:
            self._events.append(event)
            self.version += 1

    def first_sight(self, stop_id: str) -> bool:
        """True the first time ``stop_id`` is seen (bounded memory of recent ids)."""
        with self._lock:
            if stop_id in self._stop_ids:
                return False
            self._stop_ids[stop_id] = None
            while len(self._stop_ids) > MAX_STOP_IDS:
                self._stop_ids.popitem(last=False)
            return True

    def newest(self, count: int = SHOWN_EVENTS) -> list[Event]:
        """Up to ``count`` events, newest first."""
        with self._lock:
            return list(self._events)[-count:][::-1]

    def clear(self) -> None:
        """Forget everything (a replay scrubbed backwards rebuilds its log)."""
        with self._lock:
            self._events.clear()
            self._stop_ids.clear()
            self.version += 1

    def html(self, count: int = SHOWN_EVENTS) -> str:
        """The panel: a table, newest first, local wall-clock times to the second."""
        rows = []
        for event in self.newest(count):
            when = time.strftime("%H:%M:%S", time.localtime(event.wall_ns / 1e9))
            colour = KIND_COLOUR.get(event.kind, "#000000")
            cells = (
                f"<td style='padding:0 4px;white-space:nowrap'>{when}</td>"
                f"<td style='padding:0 4px;color:{colour};font-weight:bold'>{event.kind}</td>"
                f"<td style='padding:0 4px'>{html.escape(event.arm or 'fleet')}</td>"
                f"<td style='padding:0 4px'>{html.escape(event.text)}</td>"
            )
            rows.append(f"<tr data-kind='{event.kind}'>{cells}</tr>")
        body = "".join(rows) or "<tr><td>nothing yet</td></tr>"
        return (
            "<div style='max-height:18em;overflow-y:auto'>"
            f"<table id='event-log' style='font-size:0.75em'>{body}</table></div>"
        )
