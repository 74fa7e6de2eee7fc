"""Commands to arms: ``fleet move``, ``zero``, ``hold``, ``torque``, ``power``, ``cmd``.

Each takes an arm id, a group name or ``all`` and prints one line per arm with what happened.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import msgspec

from fleet.cli.interrupt import (
    EXIT_BOUND_S,
    EXIT_INTERRUPTED,
    Interrupted,
    hold_what_moved,
    until_interrupted,
)
from fleet.client import FleetClient, default_source
from fleet.devices import kind_of
from fleet.inventory import Inventory, InventoryError
from fleet.runtime import inventory_from_args, shutdown_event
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add the arm commands."""

    def arm_parser(name: str, help_text: str) -> argparse.ArgumentParser:
        parser = sub.add_parser(name, help=help_text)
        add_common(parser)
        parser.add_argument("target", help="arm id, group name, or 'all'")
        parser.add_argument(
            "--wait", action="store_true", help="wait until feedback shows the target reached"
        )
        parser.add_argument(
            "--timeout", type=float, default=10.0, help="seconds to wait for --wait"
        )
        parser.add_argument("--json", action="store_true", help="print the replies as JSON")
        parser.add_argument(
            "--takeover", action="store_true", help="take the arms from their current owner"
        )
        parser.add_argument(
            "--sync",
            action="store_true",
            help="through the coordinator: one owner, all arms start at the same time; refused "
            "(no arm moves) if any target is offline, not ok or stopped",
        )
        parser.add_argument(
            "--partial",
            action="store_true",
            help="with --sync: move the arms that can, even if some cannot",
        )
        return parser

    move = arm_parser("move", "move joints: --angles A0..A6, or --joint J --angle A")
    move.add_argument(
        "--angles",
        type=finite_float,
        nargs=7,
        metavar="DEG",
        help="7 values in degrees: joints 0..5, then the gripper (joint 6)",
    )
    move.add_argument("--joint", type=int, help="wire id 0..6 (6 is the gripper)")
    move.add_argument("--angle", type=finite_float, metavar="DEG", help="degrees")
    move.add_argument(
        "--mode", type=int, choices=(0, 1), default=1, help="0 small, 1 large smoothing"
    )
    move.set_defaults(run=run_move)

    arm_parser("zero", "return to zero").set_defaults(run=lambda a: _send(a, m.Zero(**_opts(a))))
    arm_parser("hold", "hold the measured pose").set_defaults(
        run=lambda a: _send(a, m.Hold(**_opts(a)))
    )

    torque = arm_parser("torque", "enable (on) or unload (off) joint motors")
    torque.add_argument("state", choices=("on", "off"))
    torque.add_argument("--joint", type=int, default=None, help="one joint (default all)")
    torque.add_argument(
        "--strength",
        type=int,
        default=None,
        help="all joints only: funcode 5 mode, 1..80000 (default: the arm's enable_mode; the "
        "spec's table reads 1 as enable, its note 0..80000 as strength, 80000 fully locked)",
    )
    torque.set_defaults(
        run=lambda a: _send(
            a,
            m.Torque(on=a.state == "on", joint=a.joint, strength=a.strength, **_opts(a)),
        )
    )

    power = arm_parser("power", "switch the motors' power")
    power.add_argument("state", choices=("on", "off"))
    power.set_defaults(run=lambda a: _send(a, m.Power(on=a.state == "on", **_opts(a))))

    raw = arm_parser(
        "cmd",
        "send a key-space command given as JSON to an arm, group or device, e.g. "
        '\'{"op":"zero"}\', or to gripper gl \'{"op": "move", "open_pct": 40}\'',
    )
    raw.add_argument("json_command")
    raw.set_defaults(run=run_raw)


def _opts(args: argparse.Namespace) -> dict[str, object]:
    options: dict[str, object] = {"wait_reached": args.wait, "timeout_s": args.timeout}
    if args.takeover:
        options |= {"owner": default_source(), "takeover": True}
    return options


def finite_float(text: str) -> float:
    """An angle from the command line: a finite number (``nan`` or ``inf`` would reach the wire
    as ``null``)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number of degrees")
    return value


def run_move(args: argparse.Namespace) -> int:
    """``fleet move``."""
    if args.angles is not None:
        command: m.ArmCommand = m.MoveJoints(
            angles_deg=list(args.angles), mode=args.mode, **_opts(args)
        )
    elif args.joint is not None and args.angle is not None:
        command = m.MoveJoint(joint=args.joint, angle_deg=args.angle, **_opts(args))
    else:
        print("fleet move: give --angles (7 values) or --joint and --angle", file=sys.stderr)
        return 2
    return _send(args, command)


def run_raw(args: argparse.Namespace) -> int:
    """``fleet cmd``: to an arm or group (an arm command), or to a device (its kind's)."""
    inventory = inventory_from_args(args)
    device = device_id(inventory, args.target)
    if device is not None:
        return _send_device(args, inventory, device)
    try:
        command = payloads.COMMAND.decode(args.json_command)
    except payloads.PayloadError as exc:
        print(f"fleet cmd: {exc}", file=sys.stderr)
        return 2
    return _send(args, command)


def _send(args: argparse.Namespace, command: m.ArmCommand) -> int:
    inventory = inventory_from_args(args)
    arms = inventory.resolve(args.target)
    # Ctrl-C while the command waits (a move with --wait takes seconds): hold what it moved.
    stop = shutdown_event(quiet=True, bound_s=EXIT_BOUND_S)
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        try:
            replies, skew, error = until_interrupted(
                lambda: _exchange(client, args, arms, command), stop
            )
        except Interrupted:
            what = f"fleet {args.command}"
            if not isinstance(command, m.MOTION_OPS):
                print(f"{what}: interrupted before every reply; the command was sent")
                return EXIT_INTERRUPTED
            sync_target = args.target if args.sync else ""
            return hold_what_moved(client, arms, command.owner, what, sync_target)
    if error is not None:
        print(f"FAILED [{error.code}] {error.message}")
        return 3 if error.code == ErrorCode.NO_AGENT else 1
    for reply in replies:
        if args.json:
            print(msgspec.json.encode(reply).decode())
        elif reply.ok:
            reached = "" if reply.reached is None else f", reached={reply.reached}"
            print(f"{reply.arm}: ok (seq {reply.seq}, {reply.latency_ms:.1f} ms{reached})")
        else:
            err = reply.error
            print(f"{reply.arm}: FAILED [{err.code if err else '?'}] {err.message if err else ''}")
    if skew is not None and not args.json:
        print(f"start skew across arms: {skew:.2f} ms")
    if all(r.ok for r in replies):
        return 0
    unreachable = all(
        r.ok or (r.error is not None and r.error.code == ErrorCode.NO_AGENT) for r in replies
    )
    return 3 if unreachable else 1


def _exchange(
    client: FleetClient, args: argparse.Namespace, arms: list[str], command: m.ArmCommand
) -> tuple[list[m.CommandReply], float | None, m.ErrorInfo | None]:
    """Send ``command`` to ``arms`` (through the coordinator with --sync) and wait for the
    replies: (replies, start skew with --sync, the coordinator's refusal)."""
    if args.sync:
        multi = client.multi(args.target, command, partial=args.partial)
        if multi.error is not None:
            return [], None, multi.error
        return list(multi.replies.values()), multi.start_skew_ms, None
    with ThreadPoolExecutor(max_workers=min(16, len(arms))) as pool:
        return list(pool.map(lambda arm: client.command(arm, command), arms)), None, None


def device_id(inventory: Inventory, target: str) -> str | None:
    """The device ``target`` names (``gl``, or ``gripper/gl`` with its own kind's word), or
    None when it names none."""
    kind, _, name = target.rpartition("/")
    if name not in inventory.devices:
        return None
    return name if kind in ("", kind_of(inventory.device(name)).key) else None


def unit_id(inventory: Inventory, target: str) -> str:
    """The arm or device ``target`` names: ``a1`` or ``arm/a1``, ``gl`` or ``gripper/gl`` (the
    way stops and statuses name them); InventoryError naming the known units otherwise."""
    device = device_id(inventory, target)
    if device is not None:
        return device
    kind, _, name = target.rpartition("/")
    if kind in ("", keys.ARM) and name in inventory.arms:
        return name
    labels = [*inventory.arms, *(f"{kind_of(d).key}/{d.id}" for d in inventory.devices.values())]
    raise InventoryError(
        f"{inventory.path}: no arm or device {target!r} (known: {', '.join(labels) or 'none'})"
    )


def _send_device(args: argparse.Namespace, inventory: Inventory, device: str) -> int:
    kind = kind_of(inventory.device(device))
    try:
        command = kind.payloads[keys.CMD].decode(args.json_command)
    except payloads.PayloadError as exc:
        print(f"fleet cmd: {exc}", file=sys.stderr)
        return 2
    if args.takeover:
        command = msgspec.structs.replace(command, owner=default_source(), takeover=True)
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        reply = client.device_command(device, command)
    if args.json:
        print(msgspec.json.encode(reply).decode())
    elif reply.ok:
        result = f": {reply.result}" if reply.result is not None else ""
        print(f"{kind.key}/{device}: ok{result}")
    else:
        error = reply.error or m.ErrorInfo(int(ErrorCode.UNKNOWN), "no error given")
        print(f"{kind.key}/{device}: FAILED {error.code} {error.message}")
    return 0 if reply.ok else 1
