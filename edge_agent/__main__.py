"""``edge-agent``: relay the arms of one network interface into the fleet's key space."""

from __future__ import annotations

import argparse
import logging
import sys
import threading
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


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="edge-agent", description=__doc__)
    add_inventory_options(parser)
    add_observe_options(parser)
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--arm", action="append", help="arm id to serve (repeatable)")
    which.add_argument("--interface", help="serve every arm of the inventory on this interface")
    which.add_argument(
        "--device",
        action="append",
        help="serve this device (gripper, G1; repeatable) in a devices-only agent process",
    )
    parser.add_argument(
        "--state-dir",
        type=Path,
        default=None,
        help="where latched stops are kept across restarts (default $D1_FLEET_STATE_DIR, "
        "else ~/.local/state/d1-fleet)",
    )
    return parser.parse_args(argv)


def agent_principal(inventory: Inventory, arms: list[str]) -> str:
    """The principal of an agent serving ``arms``: their ``agent`` (one certificate per
    process, so with security on every arm it serves must name the same agent)."""
    names = sorted({inventory.arm(a).agent for a in arms})
    if len(names) > 1 and inventory.security.enabled:
        raise InventoryError(
            f"{inventory.path}: arms {', '.join(arms)} name different agents ({', '.join(names)}); "
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
    if args.device:
        return run_devices(args, stop)
    try:
        inventory = inventory_from_args(args)
        arms = args.arm or [a.id for a in inventory.arms.values() if a.interface == args.interface]
        if not arms:
            raise InventoryError(f"{inventory.path}: no arm uses interface {args.interface!r}")
        inventory = inventory.with_principal(args.principal or agent_principal(inventory, arms))
        agent = EdgeAgent(inventory, arms, args.state_dir)
    except (InventoryError, RouterUnreachable, ValueError) as exc:
        print(f"edge-agent: {exc}", file=sys.stderr)
        return 2
    from edge_agent.metrics import agent_collectors

    with agent:
        agent.start()
        log.info("serving arms %s of fleet %r", ", ".join(arms), inventory.fleet)
        collectors = lambda: agent_collectors(agent)  # noqa: E731
        with Observed(agent.relay.session, inventory, "agent", args.metrics_port, arms, collectors):
            while not stop.wait(0.1) and not agent.failed.is_set():
                pass
    if agent.failed.is_set():
        log.error(
            "%s; every arm was stopped and latched before shutting down: restart the agent",
            agent.guard.failure,
        )
        return EXIT_THREAD_FAILED
    log.info("stopped")
    return 0


def run_devices(args: argparse.Namespace, stop: threading.Event) -> int:
    """``edge-agent --device ID ...``: the devices' host (``edge_agent/devices.py``)."""
    from edge_agent.devices import DeviceHost

    try:
        inventory = inventory_from_args(args)
        for device in args.device:
            inventory.device(device)
        principal = args.principal or inventory.device(args.device[0]).agent
        host = DeviceHost(inventory.with_principal(principal), args.device)
    except (InventoryError, RouterUnreachable, ValueError) as exc:
        print(f"edge-agent: {exc}", file=sys.stderr)
        return 2
    with host:
        host.start()
        log.info("serving devices %s of fleet %r", ", ".join(args.device), inventory.fleet)
        # A failed thread has latched every device already (DeviceHost._on_failure).
        while not stop.wait(0.5) and not host.failed.is_set():
            pass
    if host.failed.is_set():
        log.error("%s; every device was stopped before shutting down", host.guard.failure)
        return EXIT_THREAD_FAILED
    log.info("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())
