"""The coordinator's request desk: ``coordinator/cmd`` queries served side by side, bounded.

A multi-arm request can wait minutes for its arms to reach their targets, so requests run on a
pool of ``MAX_ACTIVE_REQUESTS`` workers. Nothing queues without bound and nothing goes
unanswered: the Zenoh callback queues at most ``QUERY_DEPTH`` requests and answers one more
4003 "busy" itself (replying in a queryable's callback is Zenoh's own pattern); a request that
finds every worker occupied is answered "busy" at once instead of waiting behind them.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import zenoh

from fleet.guard import ThreadGuard
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, ErrorInfo, encode
from fleet.wire.replies import answer

MAX_ACTIVE_REQUESTS = 4
"""Multi-arm requests served at once; one more is answered 4003 "busy" at once."""
QUERY_DEPTH = 64
"""Requests waiting for the desk; beyond it they are answered "busy"."""
BUSY_WHY = (
    f"the coordinator is busy ({MAX_ACTIVE_REQUESTS} requests in progress); retry when one finishes"
)

Serve = Callable[[bytes, str], m.MultiArmReply]
"""(payload, the requester's principal from the key) -> the reply."""


def _principal(query: zenoh.Query) -> str | None:
    chunk = str(query.key_expr).rpartition("/")[2]
    return chunk if keys.is_name(chunk) else None


def error_reply(code: ErrorCode, why: str) -> m.MultiArmReply:
    """A reply that sent nothing to any arm."""
    return m.MultiArmReply(False, {}, None, ErrorInfo(int(code), why[:1000]))


class RequestDesk:
    """Queues ``coordinator/cmd`` queries and serves them with ``serve`` on a bounded pool."""

    def __init__(self, space: keys.KeySpace, serve: Serve, guard: ThreadGuard) -> None:
        self._space = space
        self._serve = serve
        self._guard = guard
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._queries: deque[zenoh.Query] = deque()
        self._pool = ThreadPoolExecutor(
            max_workers=MAX_ACTIVE_REQUESTS, thread_name_prefix="multi-arm"
        )
        # Guarded by _lock:
        self.active = 0
        self.busy = 0
        self.bad_keys = 0
        """Requests on a key naming no usable principal (answered 2001)."""

    def on_query(self, query: zenoh.Query) -> None:
        """Zenoh thread: queue the request; if the queue is full, answer it "busy" now."""
        with self._lock:
            queued = len(self._queries) < QUERY_DEPTH
            if _principal(query) is None:
                self.bad_keys += 1  # answered by a worker, with the reason
            if queued:
                self._queries.append(query)
            else:
                self.busy += 1
        if queued:
            self._wake.set()
        else:
            self._reply(query, error_reply(ErrorCode.BUSY, BUSY_WHY))

    def counters(self) -> tuple[int, int, int]:
        """(busy answers, requests being served, requests on a key naming no principal)."""
        with self._lock:
            return self.busy, self.active, self.bad_keys

    def run(self, stopping: threading.Event) -> None:
        """The ``multi-arm`` thread: hand requests to the pool or answer them "busy"."""
        while not stopping.is_set():
            self._wake.wait(0.2)
            with self._lock:
                query = self._queries.popleft() if self._queries else None
                refuse = query is not None and self.active >= MAX_ACTIVE_REQUESTS
                if refuse:
                    self.busy += 1
                elif query is not None:
                    self.active += 1
                if not self._queries:
                    self._wake.clear()
            if query is not None and refuse:
                self._reply(query, error_reply(ErrorCode.BUSY, BUSY_WHY))
            elif query is not None:
                self._pool.submit(self._guard.wrap(self._answer, "multi-arm request"), query)

    def _answer(self, query: zenoh.Query) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            principal = _principal(query)
            if principal is None:
                why = keys.no_principal_why(str(query.key_expr))
                self._reply(query, error_reply(ErrorCode.PARAMETER, why))
            else:
                self._reply(query, self._serve(payload, principal))
        finally:
            with self._lock:
                self.active -= 1
            self._wake.set()

    def _reply(self, query: zenoh.Query, reply: m.MultiArmReply) -> None:
        # On the requester's own key (a concrete key that intersects the query's).
        answer(query, f"{self._space.prefix}/{keys.COORDINATOR_CMD}", encode(reply))

    def close(self) -> None:
        """Drop pending requests (their callers see no reply) and stop the pool."""
        self._pool.shutdown(wait=False, cancel_futures=True)
