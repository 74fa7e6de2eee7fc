"""The choreographies the viewer knows of (``choreo/<principal>``, fleet/choreo/announce.py):
each player's newest state, a status line per dance, and events when one starts, completes
or stops, with the reason.

When the demo's dance stopped, nothing in the viewer said so: the arms just stood. Now the
player's end (``aborted`` with its reason) is an event and a red status line, and a player
seen playing that falls silent for ``SILENT_S`` (killed, or its host hangs) is one too.
Bounded: the newest ``MAX_PLAYERS`` players are kept. Thread-safe: Zenoh callbacks add, the
render thread reads (``views``, which also notices silence).
"""

from __future__ import annotations

import html
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass

from fleet.choreo.announce import SILENT_S
from fleet.wire import messages as m
from viewer.events import DANCE, DANCE_STOPPED, EventLog

MAX_PLAYERS = 16
"""Players remembered (a player that starts over after each stop is a new one)."""
SHOWN_DANCES = 3
"""Status lines shown (the newest players)."""
SILENT = "silent"
"""A ``DanceView.state`` of the viewer's own: the player fell silent while playing."""


@dataclass(frozen=True)
class DanceView:
    """One player's dance as the viewer last heard it. ``state``: ``playing``, ``completed``,
    ``aborted`` or ``silent``; ``age_s``: since its last state arrived."""

    player: str
    principal: str
    script: str
    state: str
    reason: str
    iteration: int
    step: str
    age_s: float
    wall_ns: int


def _where_of(iteration: int, step: str) -> str:
    """Where in the script a player was: ``pass 3, step 'ripple'``."""
    return f"pass {iteration + 1}, step {step!r}" if step else "before the start"


def _where(status: m.ChoreoStatus) -> str:
    return _where_of(status.iteration, status.step)


class DanceTracker:
    """The newest ``ChoreoStatus`` of each player, and its events in ``events``."""

    def __init__(self, events: EventLog) -> None:
        self.events = events
        self._lock = threading.Lock()  # guards _players
        # player -> (principal, newest status, when it arrived (clock s), wall ns, silent)
        self._players: OrderedDict[str, tuple[str, m.ChoreoStatus, float, int, bool]] = (
            OrderedDict()
        )

    def clear(self) -> None:
        """Forget every player (a replay scrubbed backwards)."""
        with self._lock:
            self._players.clear()

    def on_status(
        self, principal: str, status: m.ChoreoStatus, now_s: float, wall_ns: int | None
    ) -> None:
        """A player's state arrived (``principal``: from its key)."""
        wall = wall_ns or time.time_ns()
        with self._lock:
            before = self._players.get(status.player)
            self._players[status.player] = (principal, status, now_s, wall, False)
            self._players.move_to_end(status.player)
            while len(self._players) > MAX_PLAYERS:
                self._players.popitem(last=False)
        was = None if before is None else before[1].state
        if was == status.state and not (before is not None and before[4]):
            return
        name = f"{status.script!r}"
        if status.state == "playing" and was is None:
            self.events.add(DANCE, None, f"{name} playing ({principal}, {_where(status)})", wall)
        elif status.state == "completed":
            self.events.add(DANCE, None, f"{name} completed", wall)
        elif status.state == "aborted":
            why = status.reason or "no reason given"
            text = f"{name} STOPPED: {why} ({_where(status)})"
            self.events.add(DANCE_STOPPED, None, text, wall)

    def views(self, now_s: float) -> tuple[DanceView, ...]:
        """Every known dance, newest first; a playing one silent for ``SILENT_S`` is logged
        (once) and shown as ``silent``."""
        fell_silent = []
        views = []
        with self._lock:
            for player, (principal, status, at_s, wall, silent) in self._players.items():
                if status.state == "playing" and not silent and now_s - at_s > SILENT_S:
                    silent = True
                    self._players[player] = (principal, status, at_s, wall, True)
                    fell_silent.append(status)
                state = SILENT if silent else status.state
                views.append(
                    DanceView(
                        player,
                        principal,
                        status.script,
                        state,
                        status.reason,
                        status.iteration,
                        status.step,
                        now_s - at_s,
                        wall,
                    )
                )
        for status in fell_silent:
            why = f"its player fell silent (no state for {SILENT_S:g} s: killed, or its host hangs)"
            self.events.add(DANCE_STOPPED, None, f"{status.script!r} STOPPED: {why}")
        return tuple(reversed(views))


def dance_html(views: tuple[DanceView, ...]) -> str:
    """The status lines of the newest dances (empty when there is none): a stopped one in red
    with its reason, so an operator sees at a glance that and why the dance stopped."""
    lines = []
    for view in views[:SHOWN_DANCES]:
        name = html.escape(repr(view.script))
        where = html.escape(_where_of(view.iteration, view.step))
        if view.state == "playing":
            text, colour = f"Dance {name}: playing ({where})", "#1e8449"
        elif view.state == "completed":
            text, colour = f"Dance {name}: completed", "#555555"
        else:
            why = view.reason if view.state == "aborted" else "its player fell silent"
            when = time.strftime("%H:%M:%S", time.localtime(view.wall_ns / 1e9))
            text = f"Dance {name} STOPPED at {when}: {html.escape(why)} ({where})"
            colour = "#c0392b"
        lines.append(
            f"<div data-dance-state='{view.state}' style='color:{colour};font-weight:bold'>"
            f"{text}</div>"
        )
    return f"<div id='dance-status' style='font-size:0.85em;padding:0 8px'>{''.join(lines)}</div>"
