"""One shared intake for stops and resets: arrival order in every process that takes both.

A reset put right after a stop must never overtake it, nor a stop the reset before it (before,
the coordinator, whose stop and reset subscribers each ran on a Python thread of their own,
applied a reset after the stop that followed it in 4 of 12 runs, and its heartbeat then did not
repeat the new stop). Two things keep the order, and every process that takes both (the edge
agent, the coordinator, the viewer) uses both:

- ``direct``: the callbacks of the stop and reset subscribers run on the Zenoh thread that
  received the sample, in the order it received them (zenoh-python otherwise gives every callback
  a thread of its own, and two threads race). Such a callback must only decode and hand off.
- ``ControlFifo``: one bounded FIFO in arrival order, emptied by the process's own thread. A stop
  that finds it full is not lost: its target is marked and handed out (after the FIFO) as a
  stop without a request; any other event is counted and dropped (a dropped reset releases
  nothing: failing safe keeps the latch).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Hashable
from typing import Any, Generic, TypeVar

import zenoh

E = TypeVar("E")

CONTROL_DEPTH = 1024
"""Stops and resets waiting for the thread that applies them (each takes well under 1 ms)."""


def direct(callback: Callable[[Any], object]) -> zenoh.handlers.Callback[Any]:
    """``callback`` run on the Zenoh thread that received the sample (it must not block)."""
    return zenoh.handlers.Callback(callback, indirect=False)


class ControlFifo(Generic[E]):
    """Stops and resets (and other control events) in arrival order, bounded.

    ``flooded(target)`` makes the event handed out for a stop that found the FIFO full."""

    def __init__(self, flooded: Callable[[Any], E], depth: int = CONTROL_DEPTH) -> None:
        self.wake = threading.Event()
        self._flooded_event = flooded
        self._depth = depth
        self._lock = threading.Lock()  # guards the deque and the marks
        self._events: deque[E] = deque()
        self._flooded: dict[Hashable, None] = {}  # targets of stops that found the FIFO full

    def __len__(self) -> int:
        return len(self._events)

    def push(self, event: E, stop_target: Hashable | None = None, *, is_stop: bool = False) -> bool:
        """Append ``event``; a full FIFO marks a stop's ``stop_target`` (bounded: the targets
        are the process's units and None). False when not queued (the caller counts a
        dropped event that is not a stop)."""
        with self._lock:
            queued = len(self._events) < self._depth
            if queued:
                self._events.append(event)
            elif is_stop:
                self._flooded[stop_target] = None
        if queued or is_stop:
            self.wake.set()
        return queued

    def take(self) -> list[E]:
        """Everything pending in arrival order, then one flood stop per marked target."""
        with self._lock:
            events = list(self._events)
            self._events.clear()
            events += [self._flooded_event(target) for target in self._flooded]
            self._flooded.clear()
        return events
