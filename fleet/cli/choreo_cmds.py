"""``fleet play`` (choreography files) and ``fleet mirror`` (leader/follower teleoperation)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from fleet.choreo.g1_arms import g1_ids
from fleet.choreo.script import MAX_LOOPS, Script, ScriptError, parse_script
from fleet.choreo.timeline import Frame
from fleet.client import FleetClient
from fleet.inventory import Inventory
from fleet.runtime import inventory_from_args, shutdown_event
from fleet.tomlfile import TomlError, brief, read_text

DEFAULT_SCRIPT = "choreo/demo.toml"


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``play`` and ``mirror``."""
    play = sub.add_parser("play", help="play a choreography file on its arms")
    add_common(play)
    play.add_argument("script", nargs="?", default=DEFAULT_SCRIPT, help="a choreography TOML")
    play.add_argument(
        "--loops", type=int, default=None, help="override the script's loops (0 = forever)"
    )
    play.add_argument("--check", action="store_true", help="validate against the measured poses")
    play.add_argument("--quiet", action="store_true", help="no progress lines")
    play.add_argument(
        "--ready-s", type=float, default=3.0, help="wait this long for the arms to be ready"
    )
    play.add_argument(
        "--again",
        action="store_true",
        help="after an abort, wait for the arms to be ready (e.g. reset) and start over",
    )
    play.set_defaults(run=run_play)

    mirror = sub.add_parser("mirror", help="followers copy a leader arm moved by hand (D1-T)")
    add_common(mirror)
    mirror.add_argument("--leader", required=True, help="the arm moved by hand (unloaded)")
    mirror.add_argument("--follower", action="append", required=True, help="repeatable")
    mirror.add_argument(
        "--invert",
        action="append",
        default=[],
        metavar="ARM:J[,J..]",
        help="negate these joints for that follower (mirror-image set-ups)",
    )
    mirror.add_argument(
        "--limit",
        action="append",
        default=[],
        metavar="ARM:J=LO:HI",
        help="narrow a follower joint's range, degrees",
    )
    mirror.add_argument("--for-s", type=float, default=None, help="stop after this many seconds")
    mirror.add_argument("--keep-torque", action="store_true", help="do not unload the leader")
    mirror.set_defaults(run=run_mirror)


def load_script(path: str, inventory: Inventory, loops: int | None = None) -> Script:
    """Read and parse a choreography against the inventory (ScriptError names file and path)."""
    try:
        text = read_text(path)
    except TomlError as exc:
        raise ScriptError(f"{path}: {exc}") from None
    script = parse_script(text, path, list(inventory.arms), inventory.groups, g1_ids(inventory))
    if loops is not None:
        from dataclasses import replace

        if loops > MAX_LOOPS:
            raise ScriptError(f"--loops: at most {MAX_LOOPS} (0 = forever), got {brief(loops)}")
        script = replace(script, loops=max(0, loops))
    return script


def _progress(frame: Frame) -> None:
    left = "forever" if frame.total_left_s is None else f"{frame.total_left_s:5.1f} s left"
    print(
        f"[pass {frame.iteration + 1}] step {frame.step_index} {frame.label!r} ({frame.kind}, "
        f"{frame.step_left_s:.1f} s) - {left}",
        flush=True,
    )


def run_play(args: argparse.Namespace) -> int:
    """``fleet play``: exit 0 completed, 1 aborted (the reason is printed), 2 invalid script."""
    from fleet.choreo.player import Abort, Player

    inventory = inventory_from_args(args)
    try:
        script = load_script(args.script, inventory, args.loops)
    except ScriptError as exc:
        print(f"fleet play: {exc}", file=sys.stderr)
        return 2
    stop = shutdown_event()
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        player = Player(client, script, on_progress=None if args.quiet else _progress)
        if args.check:
            try:
                player.check(ready_s=args.ready_s)
            except ScriptError as exc:
                print(f"fleet play: {exc}", file=sys.stderr)
                return 2
            except Abort as exc:
                print(f"fleet play: cannot check: {exc}", file=sys.stderr)
                return 1
            print(f"{script.source}: ok ({len(script.steps)} steps, {script.iteration_s:g} s/pass)")
            return 0
        while True:
            try:
                result = player.play(stop, ready_s=args.ready_s)
            except ScriptError as exc:
                print(f"fleet play: {exc}", file=sys.stderr)
                return 2
            if result.ok or not args.again or stop.is_set():
                break
            print(f"ABORTED: {result.reason}; starting over once the arms are ready", flush=True)
            stop.wait(2.0)
            player = Player(client, script, on_progress=player.on_progress)
    skew = "n/a" if result.start_skew_ms is None else f"{result.start_skew_ms:.2f} ms"
    worst = max(result.keyframe_error_deg, default=0.0)
    outcome = "completed" if result.ok else f"ABORTED: {result.reason}"
    print(
        f"{outcome} after {result.elapsed_s:.1f} s; "
        f"start skew {skew}, keyframe error max {worst:.2f} deg, "
        f"path error max {result.max_path_error_deg:.2f} deg",
        flush=True,
    )
    return 0 if result.ok else 1


def run_mirror(args: argparse.Namespace) -> int:
    """``fleet mirror``: exit 0 when stopped by the operator or ``--for-s``, 1 when the leader
    was lost or an arm stopped (the followers are held), 2 bad options."""
    from fleet.teleop.mapping import MappingError, parse_mappings
    from fleet.teleop.mirror import Mirror

    inventory = inventory_from_args(args)
    for arm in [args.leader, *args.follower]:
        inventory.arm(arm)
    try:
        mappings = parse_mappings(args.follower, args.invert, args.limit)
        if args.leader in args.follower:
            raise MappingError(f"arm {args.leader!r} cannot follow itself: pick another follower")
    except MappingError as exc:
        print(f"fleet mirror: {exc}", file=sys.stderr)
        return 2
    stop = shutdown_event()
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        mirror = Mirror(client, args.leader, mappings, unload_leader=not args.keep_torque)
        result = mirror.run(stop, for_s=args.for_s)
    print(result.summary(), flush=True)
    return 0 if result.ok else 1
