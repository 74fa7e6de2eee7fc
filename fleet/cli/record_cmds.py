"""``fleet record`` (key space -> MCAP) and ``fleet replay`` (MCAP -> viewer, or onto an arm)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from fleet.client import FleetClient
from fleet.runtime import inventory_from_args, shutdown_event

if TYPE_CHECKING:
    from fleet.record.reader import Recording


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``record`` and ``replay``."""
    record = sub.add_parser("record", help="record arms' keys to an MCAP file (Foxglove opens it)")
    add_common(record)
    record.add_argument(
        "--arm", action="append", help="arm, group or 'all' (repeatable; default all)"
    )
    record.add_argument("-o", "--output", default=None, help="file (default fleet-<time>.mcap)")
    record.add_argument("--for-s", type=float, default=None, help="stop after this many seconds")
    record.set_defaults(run=run_record)

    replay = sub.add_parser(
        "replay",
        help="publish a recording on the read-only fleet <fleet>-replay (`fleet viewer --replay "
        "FILE` shows a file in the viewer), or drive one arm with it (--onto)",
    )
    add_common(replay)
    replay.add_argument("file", help="an MCAP file written by `fleet record`")
    replay.add_argument(
        "--fleet", default=None, help="read-only target fleet (default <fleet>-replay)"
    )
    replay.add_argument("--speed", type=float, default=1.0, help="read-only playback speed")
    replay.add_argument("--onto", default=None, metavar="ARM", help="drive this arm (drag-teach)")
    replay.add_argument("--arm", default=None, help="the recorded arm to use with --onto")
    replay.set_defaults(run=run_replay)


def run_record(args: argparse.Namespace) -> int:
    """``fleet record``: until Ctrl-C or ``--for-s``; prints what it wrote, what it lost and
    the joints' gaps by seq. Exit 1 if the recorder failed (the file is finished as far as
    possible; an unfinished one is readable up to its last flush)."""
    from fleet.devices import kind_of
    from fleet.record.layout import layout_of
    from fleet.record.recorder import Recorder

    inventory = inventory_from_args(args)
    arms: list[str] = []
    for target in args.arm or ["all"]:
        if target in inventory.devices:  # a device id: its keys only (below)
            continue
        arms += [a for a in inventory.resolve(target) if a not in arms]
    path = args.output or time.strftime("fleet-%Y%m%d-%H%M%S.mcap")
    stop = shutdown_event()
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        try:
            # Devices: those of the inventory (all of them with ``all``, else those mounted on
            # a recorded arm); their state, grip events and stop acks.
            devices = {
                d: kind_of(config)
                for d, config in inventory.devices.items()
                if args.arm is None
                or "all" in args.arm
                or getattr(config, "mount", "") in arms
                or d in args.arm
            }
            layout = layout_of(inventory, arms, devices)
            extras = _extras(layout)
            rec = Recorder(
                client.session,
                client.keys,
                arms,
                path,
                layout=layout,
                extras=extras,
                devices=devices,
            )
        except OSError as exc:
            print(f"fleet record: {path}: cannot write it: {exc.strerror or exc}", file=sys.stderr)
            return 2
        with rec:
            print(f"recording {', '.join(arms)} to {path}; Ctrl-C stops", flush=True)
            deadline = None if args.for_s is None else time.monotonic() + args.for_s
            while not (stop.is_set() or rec.failed.is_set()):
                if deadline is not None and time.monotonic() >= deadline:
                    break
                stop.wait(0.2)
    print(rec.summary(), flush=True)
    if rec.error is not None or rec.finish_error is not None:
        why = rec.finish_error if rec.error is None else f"{type(rec.error).__name__}: {rec.error}"
        state = "finished" if rec.finished else "unfinished, readable up to its last flush"
        print(f"fleet record: the recorder failed ({why}); {path} is {state}", file=sys.stderr)
        return 1
    return 0


def _extras(layout: Any) -> Any:
    """The 3D channels (URDFs, foxglove.FrameTransforms of arms and G1s) for Foxglove, next to
    the keys."""
    from fleet.scene3d.frames3d import FleetFrames, RecordingExtras  # numpy, yourdfpy, foxglove

    return RecordingExtras(FleetFrames.load(layout))


def open_recording(path: str, command: str) -> Recording | None:
    """The recording at ``path``, or None after one line on stderr saying why it cannot be read
    (the caller exits 2); an unfinished one comes with a warning."""
    from fleet.record.errors import RecordError
    from fleet.record.reader import read_recording

    try:
        recording = read_recording(path)
    except OSError as exc:
        print(f"{command}: {path}: cannot read it: {exc.strerror or exc}", file=sys.stderr)
        return None
    except RecordError as exc:
        print(f"{command}: {exc}", file=sys.stderr)
        return None
    if not recording.complete:
        print(f"{command}: warning: {recording.describe()}", file=sys.stderr, flush=True)
    return recording


def run_replay(args: argparse.Namespace) -> int:
    """``fleet replay``: exit 0 done, 1 aborted on the arm, 2 bad file or limits. An unfinished
    recording (its recorder was killed) is replayed as far as it is readable, with a warning."""
    from fleet.choreo.player import Player
    from fleet.choreo.script import ScriptError
    from fleet.record.replay import (
        recorded_joints,
        replay_read_only,
        teach_script,
        usable_samples,
    )

    inventory = inventory_from_args(args)
    recording = open_recording(args.file, "fleet replay")
    if recording is None:
        return 2
    messages = recording.messages
    stop = shutdown_event()
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        if args.onto is None:
            fleet = args.fleet or f"{inventory.fleet}-replay"
            print(f"replaying {args.file} read-only as fleet/{fleet}/** (no commands)", flush=True)
            count = replay_read_only(client.session, messages, fleet, stop, args.speed)
            print(f"published {count} samples")
            return 0
        inventory.arm(args.onto)
        try:
            source, samples = recorded_joints(messages, args.arm, args.file)
            usable, skipped = usable_samples(samples)
            if skipped:
                print(
                    f"fleet replay: skipped {skipped} of {len(samples)} samples of {source} "
                    "(stamp not after the previous one, or not 7 angles)",
                    file=sys.stderr,
                )
            snap = client.snapshot([args.onto])[args.onto][1]
            if snap is None:
                print(f"fleet replay: no joints from {args.onto!r}; is its agent running?")
                return 3
            script = teach_script(usable, args.onto, tuple(snap.angles_deg), args.file)
            print(f"replaying {source}'s {len(usable)} samples onto {args.onto}", flush=True)
            result = Player(client, script).play(stop)
        except (ValueError, ScriptError) as exc:
            print(f"fleet replay: {exc}", file=sys.stderr)
            return 2
    print("completed" if result.ok else f"ABORTED: {result.reason}", flush=True)
    return 0 if result.ok else 1
