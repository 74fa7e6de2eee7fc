"""The worker side of the bench protocol (see ``bench/proc.py``): READY, wait, one JSON line."""

from __future__ import annotations

import argparse
import json
import sys
import threading
from typing import Any

from fleet.inventory import Inventory, load_inventory

__all__ = ["emit", "inventory", "load_inventory", "parser", "ready"]


def parser(description: str | None) -> argparse.ArgumentParser:
    """An argument parser with the options every worker takes."""
    result = argparse.ArgumentParser(description=description)
    result.add_argument("--inventory", required=True)
    result.add_argument("--log-level", default="WARNING")
    result.add_argument("--max-s", type=float, default=120.0, help="hard time limit")
    result.add_argument(
        "--endpoint", action="append", help="meet on this Zenoh router instead (repeatable)"
    )
    return result


def inventory(args: argparse.Namespace) -> Inventory:
    """The inventory named by ``--inventory``, on the ``--endpoint`` routers if given."""
    loaded = load_inventory(args.inventory)
    return loaded.with_endpoints(args.endpoint) if args.endpoint else loaded


def ready() -> threading.Event:
    """Announce READY; the returned Event is set when the parent closes our stdin."""
    done = threading.Event()

    def watch() -> None:
        sys.stdin.read()  # returns at EOF: the parent closed the pipe (or died)
        done.set()

    threading.Thread(target=watch, name="stdin-watch", daemon=True).start()
    print("READY", flush=True)
    return done


def emit(result: dict[str, Any]) -> None:
    """Print the one JSON result line."""
    print(json.dumps(result), flush=True)
