"""Synchronized starts: one thread writes every delayed command at its time.

A thread per delayed command let a client create thousands of OS threads (7342 delayed holds
made 2024 threads). Here a heap holds the pending starts, bounded by the agent's in-flight limit
(a delayed command is in flight), and one ``starts`` thread runs each when it is due.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable

from fleet.guard import ThreadGuard

MAX_PENDING = 4096
"""A safety net over the per-arm in-flight limit, which bounds the heap first."""


class SchedulerFull(Exception):
    """More synchronized starts are pending than ``MAX_PENDING``."""


class StartScheduler:
    """Runs callables at monotonic times on one thread. ``cancel_all`` at shutdown."""

    def __init__(self, guard: ThreadGuard, stopping: threading.Event) -> None:
        self._stopping = stopping
        self._cond = threading.Condition()
        self._heap: list[tuple[float, int, Callable[[], None]]] = []
        self._order = itertools.count()
        self.thread = guard.thread(self._run, "starts")

    def schedule(self, due_s: float, run: Callable[[], None]) -> None:
        """Run ``run`` at ``due_s`` (monotonic); raises SchedulerFull."""
        with self._cond:
            if len(self._heap) >= MAX_PENDING:
                raise SchedulerFull(f"{len(self._heap)} synchronized starts are pending")
            heapq.heappush(self._heap, (due_s, next(self._order), run))
            self._cond.notify()

    def cancel_all(self) -> int:
        """Forget every pending start (shutdown); returns how many there were."""
        with self._cond:
            count = len(self._heap)
            self._heap.clear()
            self._cond.notify()
        return count

    def wake(self) -> None:
        """Let the thread notice shutdown."""
        with self._cond:
            self._cond.notify()

    def _run(self) -> None:
        while not self._stopping.is_set():
            with self._cond:
                due: Callable[[], None] | None = None
                if self._heap and self._heap[0][0] <= time.monotonic():
                    due = heapq.heappop(self._heap)[2]
                else:
                    wait = self._heap[0][0] - time.monotonic() if self._heap else 0.5
                    self._cond.wait(timeout=min(max(wait, 0.0), 0.5))
            if due is not None:
                due()
