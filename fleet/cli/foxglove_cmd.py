"""``fleet foxglove``: the live fleet on a Foxglove WebSocket server
(fleet/scene3d/foxglove_bridge.py)."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable
from typing import Any

from fleet.cli.viewer_cmd import _origin, _token
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
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="bind address (default 127.0.0.1; another exposes the fleet's data to that "
        "network, behind the token: prefer an SSH tunnel)",
    )
    parser.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765)")
    parser.add_argument(
        "--token",
        type=_token,
        default=None,
        help="the access token (16-128 of A-Z a-z 0-9 - _) instead of a random one per run "
        "(or set D1_FLEET_FOXGLOVE_TOKEN); other users of this host can read a --token in "
        "the process list",
    )
    parser.add_argument(
        "--allow-origin",
        action="append",
        type=_origin,
        default=[],
        metavar="ORIGIN",
        help="also accept browser pages of ORIGIN (repeatable; the port's own origins and "
        "https://app.foxglove.dev always are; every client needs the token)",
    )
    add_observe_options(parser)
    parser.set_defaults(run=run_foxglove)


def run_foxglove(args: argparse.Namespace) -> int:
    """Bridge the fleet to Foxglove until SIGINT/SIGTERM."""
    from fleet.cli.processes import _port_free
    from fleet.scene3d.foxglove_bridge import (  # foxglove-sdk loads here
        BridgeRefused,
        FoxgloveBridge,
    )
    from fleet.web.access import FOXGLOVE_TOKEN_ENV as TOKEN_ENV
    from fleet.web.access import check_token

    inventory = inventory_from_args(args, "viewer")
    token = args.token or os.environ.get(TOKEN_ENV) or None
    if token is not None:
        try:
            check_token(token)
        except ValueError as exc:
            print(f"fleet foxglove: {TOKEN_ENV}: {exc}", file=sys.stderr)
            return 2
    if not _port_free(f"tcp/{args.host}:{args.port}"):
        print(
            f"fleet foxglove: port {args.port} on {args.host} is in use (another fleet "
            "foxglove, or a demo's --foxglove?); stop it or pass --port <another>",
            file=sys.stderr,
        )
        return 3
    stop = shutdown_event()
    try:
        bridge = FoxgloveBridge(inventory, args.host, args.port, token, tuple(args.allow_origin))
    except BridgeRefused as exc:
        print(f"fleet foxglove: {exc}", file=sys.stderr)
        return 2
    with bridge:
        print(
            f"d1-fleet foxglove: {bridge.url} (fleet {inventory.fleet!r}; in Foxglove: Open "
            "connection -> Foxglove WebSocket, this URL with its token; Ctrl-C stops)",
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
