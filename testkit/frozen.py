"""A slow consumer: a Zenoh client of the fleet that subscribes to the whole key space and
then stops reading (the test freezes its process with SIGSTOP), as a hung viewer, a stuck
observer or a hostile one does. Its router's queues towards it fill; the stop path must not
wait behind them.

Run as ``python -m testkit.frozen --inventory inventory.toml``; it prints ``subscribed``
once its subscription is declared, then waits for SIGTERM, which ends it at once (the default
action: a session's close could wait for a router that already gave it up).

``--lease-s``: the lease its session asks the router for. A frozen process sends no
keep-alives, so the router closes it after that lease; a third-party client with Zenoh's
default config asks for 10 s, and nothing stops a hostile one from asking for more.
"""

from __future__ import annotations

import argparse
import signal
import threading

import zenoh

from fleet.inventory import load_inventory
from fleet.security.session import credentials
from fleet.wire.keys import KeySpace
from fleet.wire.session import zenoh_config

READY = "subscribed"


def main() -> None:
    parser = argparse.ArgumentParser(prog="frozen-subscriber")
    parser.add_argument("--inventory", required=True)
    parser.add_argument("--lease-s", type=float, default=10.0)
    args = parser.parse_args()
    inventory = load_inventory(args.inventory).with_principal("viewer")
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    config = zenoh_config(
        "client",
        connect=inventory.endpoints,
        credentials=credentials(inventory, inventory.principal),
        lease_s=args.lease_s,
    )

    def ignore(_sample: zenoh.Sample) -> None:
        """Takes each sample and does nothing: once the process is frozen nothing reads."""

    session = zenoh.open(config)
    session.declare_subscriber(f"{KeySpace(inventory.fleet).prefix}/**", ignore)
    print(READY, flush=True)
    threading.Event().wait()  # until SIGTERM (or SIGKILL) ends the process


if __name__ == "__main__":
    main()
