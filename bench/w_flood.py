"""Worker: a hostile flood on one device's command key: undecodable queries (a deeply nested
JSON, as the hostile suite sends) from one Zenoh session as fast as it can, without waiting for
the answers, until the parent closes stdin; reports how many it sent."""

from __future__ import annotations

import time

from bench import workerlib
from fleet.client import FleetClient
from fleet.wire import keys
from testkit.hostile import nested


def main() -> None:
    """``python -m bench.w_flood --inventory inv.toml --device gl``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("--device", required=True)
    args = parser.parse_args()
    inventory = workerlib.inventory(args).with_principal("operator")
    payload = nested(b'"op":"move"')
    sent = 0
    with FleetClient(inventory) as client:
        key = f"{client.unit_key(args.device, keys.CMD)}/operator"
        done = workerlib.ready()
        deadline = time.monotonic() + args.max_s
        while not done.is_set() and time.monotonic() < deadline:
            client.session.get(key, payload=payload, timeout=0.5)
            sent += 1
    workerlib.emit({"sent": sent})


if __name__ == "__main__":
    main()
