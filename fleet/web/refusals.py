"""Counted, rate-limited warnings for what the viewer refuses (a foreign page's WebSocket, a
forged reset, a command from a read-only viewer).

A refusal is the peer's doing, not a bug: it is counted and logged, never raised. A hostile page
can knock thousands of times a second, so each kind is logged at most once per ``interval_s``
with the number of refusals since the last line.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable

LOG_INTERVAL_S = 5.0


class Refusals:
    """Counts refusals by kind; logs the first of each kind and then at most every interval."""

    def __init__(
        self,
        log: logging.Logger,
        interval_s: float = LOG_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.counts: Counter[str] = Counter()
        self._log = log
        self._interval_s = interval_s
        self._clock = clock
        self._lock = threading.Lock()  # guards counts and the two dicts (callers on any thread)
        self._next_log: dict[str, float] = {}
        self._unlogged: Counter[str] = Counter()

    def refuse(self, kind: str, message: str) -> None:
        """Count one refusal of ``kind``; log ``message`` unless one was logged recently."""
        now = self._clock()
        with self._lock:
            self.counts[kind] += 1
            if now < self._next_log.get(kind, -float("inf")):
                self._unlogged[kind] += 1
                return
            self._next_log[kind] = now + self._interval_s
            earlier = self._unlogged.pop(kind, 0)
        more = f" (and {earlier} more since the last report)" if earlier else ""
        self._log.warning("refused: %s%s", message, more)

    def __getitem__(self, kind: str) -> int:
        with self._lock:
            return self.counts[kind]
