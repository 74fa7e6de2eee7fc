"""``edge-agent``: relay the robots of one network interface (arms and the devices beside them)
into the fleet's key space."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from edge_agent.agent import EdgeAgent
from fleet.guard import EXIT_THREAD_FAILED
from fleet.inventory import Inventory, InventoryError
from fleet.observe import Observed, add_observe_options
from fleet.runtime import (
    LogFileError,
    add_inventory_options,
    inventory_from_args,
    setup_logging_from_args,
    shutdown_event,
)
from fleet.wire.session import RouterUnreachable

log = logging.getLogger("edge_agent")


def build_parser() -> argparse.ArgumentParser:
    """``edge-agent``'s options (docs/guide/cli.md lists them; tests/test_docs.py checks it)."""
    parser = argparse.ArgumentParser(prog="edge-agent", description=__doc__)
    add_inventory_options(parser)
    add_observe_options(parser)
    parser.add_argument(
        "--interface",
        help="serve every arm and device of the inventory on this network interface (one "
        "process per card); --arm / --device narrow it down",
    )
    parser.add_argument("--arm", action="append", help="arm id to serve (repeatable)")
    parser.add_argument(
        "--device", action="append", help="device id to serve (gripper, G1; repeatable)"
    )
    parser.add_argument(
        "--state-dir",
        type=Path,
        default=None,
        help="where latched stops are kept across restarts (default $D1_FLEET_STATE_DIR, "
        "else ~/.local/state/d1-fleet)",
    )
    return parser


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line, checked: something to serve must be named."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not (args.interface or args.arm or args.device):
        parser.error("give --interface CARD, or --arm / --device ids")
    return args


def units_to_serve(inventory: Inventory, args: argparse.Namespace) -> tuple[list[str], list[str]]:
    """The arms and devices this process serves: those on ``--interface`` (every one, or only
    the ``--arm`` / ``--device`` named), else exactly the ones named."""
    for arm in args.arm or []:
        inventory.arm(arm)
    for device in args.device or []:
        inventory.device(device)
    if args.interface is None:
        return list(args.arm or []), list(args.device or [])
    arms, devices = inventory.units_on(args.interface)
    if args.arm or args.device:
        arms = [a for a in arms if a in (args.arm or [])]
        devices = [d for d in devices if d in (args.device or [])]
    if not arms and not devices:
        raise InventoryError(
            f"{inventory.path}: no arm or device (of those named) uses interface {args.interface!r}"
        )
    return arms, devices


def agent_principal(inventory: Inventory, units: list[str]) -> str:
    """The principal of an agent serving ``units``: their ``agent`` (one certificate per
    process, so with security on every robot it serves must name the same agent)."""
    names = sorted({inventory.agent_of(u) for u in units})
    if len(names) > 1 and inventory.security.enabled:
        raise InventoryError(
            f"{inventory.path}: {', '.join(units)} name different agents ({', '.join(names)}); "
            "one agent process has one identity: give them the same `agent`"
        )
    return names[0]


def main(argv: list[str] | None = None) -> int:
    """Run until SIGINT/SIGTERM. Exit 0 on a clean stop, 2 on a configuration error."""
    args = parse_args(argv)
    try:
        setup_logging_from_args(args, role="agent")
    except LogFileError as exc:
        print(f"edge-agent: {exc}", file=sys.stderr)
        return 2
    stop = shutdown_event()
    try:
        inventory = inventory_from_args(args)
        arms, devices = units_to_serve(inventory, args)
        principal = args.principal or agent_principal(inventory, [*arms, *devices])
        inventory = inventory.with_principal(principal)
        agent = EdgeAgent(inventory, arms, args.state_dir, devices)
    except (InventoryError, RouterUnreachable, ValueError) as exc:
        print(f"edge-agent: {exc}", file=sys.stderr)
        return 2
    from edge_agent.metrics import agent_collectors

    units = [*arms, *devices]
    with agent:
        agent.start()
        served = (("arms", arms), ("devices", devices))
        what = [f"{name} {', '.join(ids)}" for name, ids in served if ids]
        log.info("serving %s of fleet %r", " and ".join(what), inventory.fleet)
        collectors = lambda: agent_collectors(agent)  # noqa: E731
        with Observed(
            agent.relay.session,
            inventory,
            "agent",
            args.metrics_port,
            units,
            collectors,
            agent.relay.datagram.path,
        ):
            while not stop.wait(0.1) and not agent.failed.is_set():
                pass
    if agent.failed.is_set():
        log.error(
            "%s; every robot was stopped and latched before shutting down: restart the agent",
            agent.guard.failure,
        )
        return EXIT_THREAD_FAILED
    log.info("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
