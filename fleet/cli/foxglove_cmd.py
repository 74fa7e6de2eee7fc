"""``fleet foxglove``: the live fleet on a Foxglove WebSocket server
(fleet/scene3d/foxglove_bridge.py)."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from typing import Any

from fleet.guard import EXIT_THREAD_FAILED
from fleet.observe import Observed, add_observe_options
from fleet.runtime import inventory_from_args, shutdown_event, wait_for

log = logging.getLogger("fleet")


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``foxglove``."""
    parser = sub.add_parser(
        "foxglove", help="serve the fleet to Foxglove (WebSocket, arms in 3D, plots, stops)"
    )
    add_common(parser)
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765)")
    add_observe_options(parser)
    parser.set_defaults(run=run_foxglove)


def run_foxglove(args: argparse.Namespace) -> int:
    """Bridge the fleet to Foxglove until SIGINT/SIGTERM."""
    from fleet.cli.processes import _port_free
    from fleet.scene3d.foxglove_bridge import FoxgloveBridge  # foxglove-sdk loads only here

    inventory = inventory_from_args(args, "viewer")
    if not _port_free(f"tcp/{args.host}:{args.port}"):
        print(
            f"fleet foxglove: port {args.port} on {args.host} is in use (another fleet "
            "foxglove, or a demo's --foxglove?); stop it or pass --port <another>",
            file=sys.stderr,
        )
        return 3
    stop = shutdown_event()
    with FoxgloveBridge(inventory, args.host, args.port) as bridge:
        print(
            f"d1-fleet foxglove: ws://{args.host}:{bridge.port} (fleet {inventory.fleet!r}; "
            "in Foxglove: Open connection -> Foxglove WebSocket; Ctrl-C stops)",
            flush=True,
        )
        with Observed(
            bridge.session,
            inventory,
            "foxglove",
            args.metrics_port,
            collectors=lambda: bridge_collectors(bridge),
        ):
            failed = wait_for(stop, bridge.failed)
    if failed:
        log.error("%s: the Foxglove bridge stopped; restart it", bridge.guard.failure)
        return EXIT_THREAD_FAILED
    return 0


def bridge_collectors(bridge: Any) -> list[Any]:
    """Messages published, samples dropped at the inbox, undecodable samples."""
    from fleet.metrics import FunctionCollector, counter

    def collect() -> list[Any]:
        return [
            counter(
                "d1_foxglove_published", "key-space samples published", [], [([], bridge.published)]
            ),
            counter(
                "d1_foxglove_dropped", "samples dropped at a full inbox", [], [([], bridge.dropped)]
            ),
            counter("d1_foxglove_bad", "undecodable samples", [], [([], bridge.bad)]),
        ]

    return [FunctionCollector(collect)]
