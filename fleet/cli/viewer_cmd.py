"""``fleet viewer``: the live 3D fleet in the browser (viser), bound to 127.0.0.1 by default.

The page and its WebSocket need this run's token (printed in the URL) and WebSockets are
accepted only from the viewer's own origins (fleet/web/access.py). The viewer acts as the principal
``viewer`` (role observer: STOP ALL only) unless ``--principal`` names one that may command.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from fleet.guard import EXIT_THREAD_FAILED
from fleet.observe import Observed, add_observe_options
from fleet.runtime import inventory_from_args, shutdown_event, wait_for

if TYPE_CHECKING:
    from viewer.app import Viewer

log = logging.getLogger("fleet")

VIEWER_PRINCIPAL = "viewer"
"""Who the viewer acts as by default (an observer: it may stop, not reset or command)."""


def _token(text: str) -> str:
    from fleet.web.access import check_token

    try:
        return check_token(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _origin(text: str) -> str:
    from fleet.web.access import check_origin

    try:
        return check_origin(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``viewer``."""
    viewer = sub.add_parser("viewer", help="serve the live 3D fleet viewer (viser) on a web port")
    add_common(viewer)
    add_observe_options(viewer)
    viewer.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to bind (default 127.0.0.1; 0.0.0.0 exposes it to every network: "
        "then pass --allow-origin for the name browsers use, and prefer an SSH tunnel)",
    )
    viewer.add_argument(
        "--port", type=int, default=8080, help="web port (default 8080; next free one if busy)"
    )
    viewer.add_argument(
        "--rate-hz", type=float, default=20.0, help="scene updates per second at most"
    )
    viewer.add_argument(
        "--token",
        type=_token,
        default=None,
        help="the access token (16-128 of A-Z a-z 0-9 - _) instead of the fleet's kept one; "
        "other users of this host can read it in the process list",
    )
    viewer.add_argument(
        "--new-token",
        action="store_true",
        help="replace the fleet's kept token (<state dir>/<fleet>/viewer.token, mode 0600) by "
        "a new one: open tabs need the new URL (the kept token survives restarts otherwise)",
    )
    viewer.add_argument(
        "--allow-origin",
        action="append",
        type=_origin,
        default=[],
        metavar="ORIGIN",
        help="also accept WebSockets from pages of ORIGIN, e.g. http://robot-pc.lab:8080 "
        "(repeatable; http://127.0.0.1:<port> and http://localhost:<port> always are)",
    )
    viewer.add_argument(
        "--read-only",
        action="store_true",
        help="STOP ALL only: no reset, no jog (always so when the principal may not command, "
        "as the default principal 'viewer', an observer)",
    )
    viewer.add_argument(
        "--replay",
        default=None,
        metavar="FILE.mcap",
        help="show a `fleet record` recording instead of the live fleet: a timeline (play, "
        "pause, scrub, speed), no command controls, no Zenoh session; the arms stand where the "
        "recording says (no inventory needed)",
    )
    viewer.set_defaults(run=run_viewer)


def run_viewer(args: argparse.Namespace) -> int:
    """Serve the viewer (of the live fleet, or of ``--replay FILE``) until SIGINT/SIGTERM."""
    if args.replay is not None:
        return run_replay_viewer(args)
    inventory = inventory_from_args(args, VIEWER_PRINCIPAL)
    role = inventory.role_of(inventory.principal)

    def describe(viewer: Viewer) -> str:
        mode = "read-only: stop only" if viewer.read_only else "stop, reset and jog"
        who = f"principal {inventory.principal!r}, role {role}: {mode}"
        return f"fleet {inventory.fleet!r}; {who}"

    from fleet.web.token_store import viewer_token

    # A restarted viewer keeps its token, so the tabs open on it keep working.
    token = args.token or viewer_token(inventory.fleet, renew=args.new_token)
    return _serve(args, describe, token, inventory=inventory, read_only=args.read_only)


def run_replay_viewer(args: argparse.Namespace) -> int:
    """``fleet viewer --replay FILE``: a recording's timeline. Exit 2 when the file cannot be
    read or holds no arm."""
    from fleet.cli.record_cmds import open_recording
    from fleet.record.errors import RecordError
    from viewer.replay import replay_source

    recording = open_recording(args.replay, "fleet viewer")
    if recording is None:
        return 2
    try:
        source = replay_source(recording)
    except RecordError as exc:
        print(f"fleet viewer: {exc}", file=sys.stderr)
        return 2
    if not source.layout_recorded:
        log.warning(
            "%s keeps no fleet layout (an older fleet record): the arms are drawn in a row",
            args.replay,
        )

    def describe(viewer: Viewer) -> str:
        timeline = viewer.timeline
        assert timeline is not None
        return (
            f"replay of {args.replay}: fleet {source.layout.fleet!r}, {len(timeline.arms)} arms, "
            f"{timeline.duration_s:.1f} s; no command controls"
        )

    return _serve(args, describe, args.token, replay=source)


def viewer_collectors(viewer: Viewer) -> list[Any]:
    """The viewer's metrics: browsers connected (read at scrape time)."""
    from fleet.metrics import FunctionCollector, gauge

    def collect() -> list[Any]:
        clients = len(viewer.server.get_clients())
        return [gauge("d1_viewer_clients", "browsers connected", [], [([], clients)])]

    return [FunctionCollector(collect)]


def _serve(
    args: argparse.Namespace, describe: Callable[[Viewer], str], token: str | None, **shows: Any
) -> int:
    """Run a viewer of ``shows`` (``inventory=`` or ``replay=``) with ``token`` (None: a
    random one) until SIGINT/SIGTERM; prints its URL and ``describe(viewer)``."""
    from viewer.app import Viewer  # viser and numpy load only for this command

    stop = shutdown_event()
    with Viewer(
        host=args.host,
        port=args.port,
        rate_hz=args.rate_hz,
        token=token,
        allow_origins=args.allow_origin,
        **shows,
    ) as viewer:
        if viewer.port != args.port:
            log.warning("port %d was busy; the viewer took %d", args.port, viewer.port)
        print(f"d1-fleet viewer: {viewer.url}  ({describe(viewer)}; Ctrl-C stops)", flush=True)
        with Observed(
            viewer.session,
            shows.get("inventory"),
            "viewer",
            args.metrics_port,
            collectors=lambda: viewer_collectors(viewer),
        ):
            failed = wait_for(stop, viewer.failed)
    if failed:
        log.error("%s: the viewer stopped; restart it", viewer.guard.failure)
        return EXIT_THREAD_FAILED
    return 0
