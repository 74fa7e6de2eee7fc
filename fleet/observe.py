"""What every long-running process adds to itself: the info queryable (``fleet doctor`` reads
versions and clocks from it) and, with ``--metrics-port``, Prometheus metrics on 127.0.0.1.

``add_observe_options`` gives a command ``--metrics-port``; ``Observed`` is the context manager
its ``run`` opens once its Zenoh session exists. Shutdown order: metrics server first (nothing
scrapes a closing process), then the queryable.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from fleet.inventory import Inventory
from fleet.wire.info import InfoService, package_version


def add_observe_options(parser: argparse.ArgumentParser) -> None:
    """``--metrics-port``."""
    parser.add_argument(
        "--metrics-port",
        type=int,
        default=None,
        metavar="PORT",
        help="serve Prometheus metrics on 127.0.0.1:PORT/metrics (off by default; 0: any port)",
    )


class Observed:
    """Info queryable and optional metrics of one process. A context manager."""

    def __init__(
        self,
        session: zenoh.Session | None,
        inventory: Inventory | None,
        role: str,
        metrics_port: int | None = None,
        arms: Iterable[str] = (),
        collectors: Callable[[], list[Any]] | None = None,
        datagram: Callable[[], str | None] | None = None,
    ) -> None:
        self.metrics = None
        if metrics_port is not None:
            from fleet.metrics import MetricsServer  # prometheus-client only when asked for

            extra = collectors() if collectors is not None else []
            self.metrics = MetricsServer(metrics_port, role, package_version(), extra)
        port = self.metrics.port if self.metrics is not None else None
        self.info = (
            None
            if session is None or inventory is None
            else InfoService(
                session, inventory.fleet, role, inventory.principal, list(arms), port, datagram
            )
        )

    def close(self) -> None:
        """Metrics first, then the info queryable (idempotent)."""
        if self.metrics is not None:
            self.metrics.close()
        if self.info is not None:
            self.info.close()

    def __enter__(self) -> Observed:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
