"""A consumer of the fleet's state, like a viewer: subscribes to every arm's joints and status
and to every device's state.

``--slow-s S`` makes it slow (each sample takes S seconds in its callback, which holds up its
Zenoh session's delivery); the test freezes another one with SIGSTOP.

``python -m tests.netlab.consumer INVENTORY [--slow-s S]`` (under ``ip netns exec``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

import zenoh

from fleet.devices import kind_of
from fleet.inventory import load_inventory
from fleet.wire import keys
from fleet.wire.session import close_bounded, open_client


def main(argv: list[str] | None = None) -> int:
    """Consume until SIGTERM; print how many samples arrived."""
    parser = argparse.ArgumentParser(prog="consumer")
    parser.add_argument("inventory")
    parser.add_argument("--slow-s", type=float, default=0.0)
    args = parser.parse_args(argv)
    inventory = load_inventory(args.inventory)
    space = keys.KeySpace(inventory.fleet)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    count = [0]

    def on_sample(_sample: zenoh.Sample) -> None:
        count[0] += 1
        if args.slow_s:
            # Slow until told to stop: then its backlog drains at once and it exits (a sleep
            # here held its shutdown until the harness killed it, 10 s later).
            stop.wait(args.slow_s)

    session = open_client(inventory.endpoints)
    try:
        subs = [
            session.declare_subscriber(space.all_arms(channel), on_sample)
            for channel in (keys.JOINTS, keys.STATUS)
        ]
        subs += [
            session.declare_subscriber(space.device(kind, "*", keys.STATE), on_sample)
            for kind in sorted({kind_of(d).key for d in inventory.devices.values()})
        ]
        print("ready", flush=True)
        stop.wait()
        for sub in subs:
            sub.undeclare()
    finally:
        close_bounded(session, "session")
    print(f"received {count[0]}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
