"""Process plumbing shared by every entry point: logging, signals, the inventory options."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import threading
from types import FrameType

from fleet.inventory import DEFAULT_INVENTORY, Inventory, InventoryError, load_inventory


def setup_logging(level: str = "INFO") -> None:
    """One log format for every process of the fleet."""
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)s %(name)s [%(threadName)s] %(message)s",
    )


def shutdown_event() -> threading.Event:
    """An Event set by SIGINT, SIGTERM or SIGHUP (its terminal closed): call from the main
    thread."""
    stop = threading.Event()

    def handler(signum: int, _frame: FrameType | None) -> None:
        logging.getLogger("fleet").info("received %s, shutting down", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGHUP, handler)
    return stop


def wait_for(stop: threading.Event, failed: threading.Event | None = None) -> bool:
    """Block the main thread until ``stop`` (a signal) or ``failed`` (a thread's guard) is
    set, waking up so signal handlers can run. True when a thread failed."""
    while not stop.wait(0.1):
        if failed is not None and failed.is_set():
            return True
    return False


CLI_CONNECT_TIMEOUT_S = 2.0
"""A command (``fleet estop`` included) fails this fast when no router answers: a stop that
waits 10 s for a router that is not there is worse than a clear error at once."""


def add_inventory_options(parser: argparse.ArgumentParser) -> None:
    """``--inventory``, ``--domain`` and ``--endpoint``: every command takes them."""
    parser.add_argument(
        "--inventory",
        default=DEFAULT_INVENTORY,
        help="fleet description (default ./inventory.toml)",
    )
    parser.add_argument(
        "--domain", type=int, default=None, help="override the inventory's DDS domain id"
    )
    parser.add_argument(
        "--endpoint",
        action="append",
        default=None,
        help="override the inventory's Zenoh endpoints (repeatable), e.g. tcp/127.0.0.1:7447",
    )
    parser.add_argument(
        "--principal",
        default=None,
        help="who this process acts as (default: $D1_FLEET_PRINCIPAL, else the process's own: "
        "operator for the CLI, coordinator, viewer, sim, router, the arms' agent)",
    )
    parser.add_argument(
        "--connect-timeout",
        type=float,
        default=CLI_CONNECT_TIMEOUT_S,
        metavar="S",
        help=f"how long a command waits for the router (default {CLI_CONNECT_TIMEOUT_S:g} s)",
    )
    parser.add_argument("--log-level", default="INFO")


PRINCIPAL_ENV = "D1_FLEET_PRINCIPAL"


def inventory_from_args(args: argparse.Namespace, principal: str = "operator") -> Inventory:
    """Load the inventory, apply the command-line overrides, and set who this process acts as:
    ``--principal``, else $D1_FLEET_PRINCIPAL, else ``principal`` (the process's default)."""
    inventory = load_inventory(args.inventory)
    if args.domain is not None:
        inventory = inventory.with_domain(args.domain)
    if args.endpoint:
        inventory = inventory.with_endpoints(args.endpoint)
    # $D1_FLEET_PRINCIPAL is the user's identity: it never renames the fleet's own processes.
    from_env = os.environ.get(PRINCIPAL_ENV) if principal == "operator" else None
    chosen = getattr(args, "principal", None) or from_env or principal
    try:
        return inventory.with_principal(chosen)
    except ValueError as exc:
        raise InventoryError(f"--principal: {exc}") from None
