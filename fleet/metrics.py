"""Prometheus metrics of a long-running process (``--metrics-port``; off by default).

Every process gets its own ``CollectorRegistry`` served on 127.0.0.1 only (``prometheus-client``'s
``start_http_server``, a daemon thread of its own). Nothing here runs on a hot path: the
collectors read counters the process keeps anyway (the agent's diag counters, the coordinator's)
when Prometheus scrapes, and latencies are handed over in a bounded deque (``LatencySink``: one
``append``, as cheap as a counter increment) and turned into histogram buckets at scrape time.

Names: ``d1_<what>`` with units in the name (``_seconds``, ``_hz``, ``_total`` for counters).
"""

from __future__ import annotations

import bisect
import collections
import logging
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from prometheus_client import CollectorRegistry, ProcessCollector, start_http_server
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector

log = logging.getLogger("fleet.metrics")

METRICS_HOST = "127.0.0.1"
LATENCY_BUCKETS_S = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
"""Command and stop latencies: 1 ms (a stop's fan-out on one host) to 10 s (a move)."""
MAX_PENDING_SAMPLES = 10_000
"""A sink keeps at most this many unscraped latencies (a process nobody scrapes loses the
oldest, counted in ``d1_metrics_samples_dropped_total``)."""


class LatencySink:
    """Latencies handed from the process's threads to the scrape: ``add`` is one deque append;
    ``drain`` (at scrape time) moves them into cumulative histogram buckets."""

    def __init__(
        self,
        buckets: tuple[float, ...] = LATENCY_BUCKETS_S,
        pending: collections.deque[float] | None = None,
    ) -> None:
        self.buckets = buckets
        # ``pending``: a deque the process appends to itself (the agent's, so that the agent
        # needs no prometheus import); else our own.
        self._pending = (
            pending if pending is not None else collections.deque(maxlen=MAX_PENDING_SAMPLES)
        )
        self._counts = [0] * (len(buckets) + 1)  # the last is +Inf
        self._sum = 0.0
        self._added = 0
        self._taken = 0
        self._lock = threading.Lock()  # guards the buckets against two concurrent scrapes

    def add(self, seconds: float) -> None:
        """One observation (any thread; no lock: deque.append is atomic)."""
        self._pending.append(seconds)
        self._added += 1  # approximate under races; only feeds the dropped count

    def drain(self) -> tuple[list[tuple[str, float]], float, int]:
        """Cumulative ``(le, count)`` buckets, the sum, and how many were dropped unscraped."""
        with self._lock:
            while True:
                try:
                    value = self._pending.popleft()
                except IndexError:
                    break
                self._taken += 1
                self._added = max(self._added, self._taken)  # an outside deque: no add()
                self._counts[bisect.bisect_left(self.buckets, value)] += 1
                self._sum += value
            cumulative, total = [], 0
            for bound, count in zip((*self.buckets, float("inf")), self._counts, strict=True):
                total += count
                cumulative.append(("+Inf" if bound == float("inf") else repr(bound), total))
            return cumulative, self._sum, max(0, self._added - self._taken)

    def family(self, name: str, doc: str, labels: dict[str, str] | None = None) -> Metric:
        """This sink as a histogram metric family."""
        buckets, total, _dropped = self.drain()
        labels = labels or {}
        family = HistogramMetricFamily(name, doc, labels=list(labels))
        family.add_metric(list(labels.values()), buckets, total)
        return family


class FunctionCollector(Collector):  # type: ignore[misc]
    """A collector whose ``collect`` is a function (the per-process collectors)."""

    def __init__(self, collect: Callable[[], Iterable[Metric]]) -> None:
        self._collect = collect

    def collect(self) -> Iterator[Metric]:
        """The process's metrics now."""
        yield from self._collect()


def gauge(name: str, doc: str, labels: list[str], rows: Iterable[tuple[list[str], Any]]) -> Metric:
    """A gauge family; rows whose value is None are left out (unknown, not zero)."""
    family = GaugeMetricFamily(name, doc, labels=labels)
    for values, value in rows:
        if value is not None:
            family.add_metric(values, float(value))
    return family


def counter(
    name: str, doc: str, labels: list[str], rows: Iterable[tuple[list[str], Any]]
) -> Metric:
    """A counter family (``name`` without ``_total``: the client adds it)."""
    family = CounterMetricFamily(name, doc, labels=labels)
    for values, value in rows:
        if value is not None:
            family.add_metric(values, float(value))
    return family


class MetricsServer:
    """The process's registry served on 127.0.0.1:``port`` (0: any free port). Closeable."""

    def __init__(
        self, port: int, role: str, version: str, collectors: Iterable[Collector] = ()
    ) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        ProcessCollector(registry=self.registry)
        info = gauge("d1_process_info", "this process (value 1)", ["role", "version"], [])
        info.add_metric([role, version], 1.0)
        self.registry.register(FunctionCollector(lambda: [info]))
        for collector in collectors:
            self.registry.register(collector)
        self._server, self._thread = start_http_server(port, METRICS_HOST, self.registry)
        self.port = int(self._server.server_address[1])
        log.info("metrics on http://%s:%d/metrics", METRICS_HOST, self.port)

    def close(self) -> None:
        """Stop serving (idempotent)."""
        if self._thread.is_alive():
            self._server.shutdown()
            self._server.server_close()
            self._thread.join(timeout=2.0)
