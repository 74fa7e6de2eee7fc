"""A flood of hostile queries on one unit's command key, in a process of its own (so that a
test measuring a stop beside it measures the fleet, not its own Python threads' contention).

Run as ``python -m testkit.cmdflood --unit a1 --inventory inventory.toml``; prints
``FLOODING`` after its first 500 queries and floods until SIGTERM (the default action ends it).
"""

from __future__ import annotations

import argparse

from fleet.client import FleetClient
from fleet.inventory import load_inventory
from fleet.wire import keys

FLOODING = "FLOODING"
PAYLOAD = b'{"op": "nope"' * 20


def main() -> None:
    parser = argparse.ArgumentParser(prog="command-flood")
    parser.add_argument("--unit", required=True)
    parser.add_argument("--inventory", required=True)
    args = parser.parse_args()
    client = FleetClient(load_inventory(args.inventory))
    key = client.unit_key(args.unit, keys.CMD) + f"/{client.principal}"
    sent = 0
    while True:
        client.session.get(key, payload=PAYLOAD, timeout=0.2)
        sent += 1
        if sent == 500:
            print(FLOODING, flush=True)


if __name__ == "__main__":
    main()
