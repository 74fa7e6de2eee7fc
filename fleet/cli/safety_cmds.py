"""``fleet estop [arm]`` and ``fleet reset [arm]``."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable

from fleet.cli.arm_commands import unit_id
from fleet.client import FleetClient
from fleet.runtime import inventory_from_args


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``estop`` and ``reset``."""
    estop = sub.add_parser(
        "estop",
        help="protective stop of every arm and device, or of one (an arm's stop also stops "
        "the devices mounted on it)",
    )
    add_common(estop)
    estop.add_argument(
        "arm", nargs="?", default=None, help="an arm or device (a1, gl, or gripper/gl)"
    )
    estop.add_argument("--reason", default="")
    estop.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for standstill")
    estop.set_defaults(run=run_estop)

    reset = sub.add_parser(
        "reset",
        help="release a latched stop of every robot, or of one arm or device (moves nothing)",
    )
    add_common(reset)
    reset.add_argument("arm", nargs="?", default=None)
    reset.add_argument(
        "--timeout", type=float, default=3.0, help="seconds to wait for every unit's answer"
    )
    reset.set_defaults(run=run_reset)


def _ms(later: int | None, earlier: int) -> str:
    return "-" if later is None else f"{(later - earlier) / 1e6:+.1f} ms"


def run_estop(args: argparse.Namespace) -> int:
    """Stop, then print per arm the times to receipt, DDS write and standstill."""
    inventory = inventory_from_args(args)
    target = None if args.arm is None else unit_id(inventory, args.arm)
    targets = [target] if target else list(inventory.arms)
    for device in [target] if target in inventory.devices else list(inventory.devices):
        if getattr(inventory.device(device), "stop_action", "") == "damp":
            print(
                f"WARNING: {device}'s stop action is damp: a damped G1 sinks to the ground "
                "(docs/design/stop-path.md); make sure nobody is next to it",
                file=sys.stderr,
            )
    for arm in [t for t in targets if t not in inventory.devices]:
        action = inventory.arm(arm).stop_action
        if action != "hold":
            print(
                f"WARNING: {arm}'s stop action is {action}: an unloaded or unpowered D1 drops "
                "under gravity (README.md, Safety); make sure nothing is under it",
                file=sys.stderr,
            )
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        sent_ns = time.time_ns()
        acks = client.estop(target, reason=args.reason, timeout_s=args.timeout)
    missing = [arm for arm, ack in acks.items() if ack is None]
    for arm, ack in acks.items():
        if ack is None:
            print(f"{arm}: NO ACK: is its edge-agent running? (its arm was not confirmed stopped)")
            continue
        confirmed = ""
        if "/" in arm:  # a device: its state confirmed the action
            print(
                f"{arm}: stopped ({ack.action}): received {_ms(ack.received_ns, sent_ns)}, "
                f"DDS written {_ms(ack.dds_written_ns, sent_ns)}, "
                f"confirmed {_ms(ack.still_ns, sent_ns)}"
                + (f" ({ack.detail})" if ack.detail else "")
            )
            continue
        if ack.action != "hold":
            state = "unloaded" if ack.action == "unload" else "unpowered"
            confirmed = f", {state} {_ms(ack.confirmed_ns, sent_ns)}"
        print(
            f"{arm}: stopped ({ack.action}): received {_ms(ack.received_ns, sent_ns)}, "
            f"DDS written {_ms(ack.dds_written_ns, sent_ns)}, still {_ms(ack.still_ns, sent_ns)}"
            + confirmed
        )
    if missing:
        return 3
    return 0 if all(a is not None and a.done for a in acks.values()) else 1


def run_reset(args: argparse.Namespace) -> int:
    """Put a reset; print what it did to each unit it reached. Exit 0 when every one was
    released or not stopped, 1 when one is still stopped, 3 when one did not answer."""
    inventory = inventory_from_args(args)
    target = None if args.arm is None else unit_id(inventory, args.arm)
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        answers = client.reset_and_report(target, timeout_s=args.timeout)
    for unit, ack in answers.items():
        if ack is None:
            print(f"{unit}: NO ANSWER: is its edge-agent running? (not known to be released)")
        elif ack.outcome == "released":
            print(f"{unit}: released ({ack.detail}; nothing moves: it stays put)")
        elif ack.outcome == "not_stopped":
            print(f"{unit}: was not stopped")
        else:
            print(f"{unit}: STILL STOPPED: reset {ack.outcome}: {ack.detail}")
    if any(ack is None for ack in answers.values()):
        return 3
    stopped = [a for a in answers.values() if a is not None and a.outcome in ("kept", "refused")]
    return 1 if stopped else 0
