"""``fleet viewer``: the live 3D fleet in the browser (viser), bound to 127.0.0.1 by default."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable

from fleet.guard import EXIT_THREAD_FAILED
from fleet.runtime import inventory_from_args, shutdown_event, wait_for

log = logging.getLogger("fleet")


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``viewer``."""
    viewer = sub.add_parser("viewer", help="serve the live 3D fleet viewer (viser) on a web port")
    add_common(viewer)
    viewer.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to bind (default 127.0.0.1; 0.0.0.0 exposes it to every network)",
    )
    viewer.add_argument(
        "--port", type=int, default=8080, help="web port (default 8080; next free one if busy)"
    )
    viewer.add_argument(
        "--rate-hz", type=float, default=20.0, help="scene updates per second at most"
    )
    viewer.set_defaults(run=run_viewer)


def run_viewer(args: argparse.Namespace) -> int:
    """Serve the viewer until SIGINT/SIGTERM."""
    from viewer.app import Viewer  # viser and numpy load only for this command

    inventory = inventory_from_args(args, "viewer")
    stop = shutdown_event()
    with Viewer(inventory, host=args.host, port=args.port, rate_hz=args.rate_hz) as viewer:
        if viewer.port != args.port:
            log.warning("port %d was busy; the viewer took %d", args.port, viewer.port)
        print(
            f"d1-fleet viewer: {viewer.url}  (fleet {inventory.fleet!r}; Ctrl-C stops)", flush=True
        )
        failed = wait_for(stop, viewer.failed)
    if failed:
        log.error("%s: the viewer stopped; restart it", viewer.guard.failure)
        return EXIT_THREAD_FAILED
    return 0
