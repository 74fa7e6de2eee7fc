"""Worker: a plain Zenoh subscriber on every arm's ``joints`` (what any client of the key space
sees). The callback only stamps and stores; decoding happens after the run."""

from __future__ import annotations

import threading
import time

import zenoh

from bench import workerlib
from bench.w_feed import marker_of
from fleet.wire import keys, payloads
from fleet.wire.session import open_client


def run(args_inventory: str, max_s: float) -> dict:
    """Record (key, payload, receive time) until stdin closes; then decode them."""
    inventory = workerlib.load_inventory(args_inventory)
    space = keys.KeySpace(inventory.fleet)
    lock = threading.Lock()
    raw: list[tuple[str, bytes, int]] = []

    def on_sample(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        item = (str(sample.key_expr), sample.payload.to_bytes(), now)
        with lock:
            raw.append(item)

    with open_client(inventory.endpoints) as session:
        subscriber = session.declare_subscriber(space.all_arms(keys.JOINTS), on_sample)
        done = workerlib.ready()
        done.wait(max_s)
        subscriber.undeclare()
    index = {arm: i for i, arm in enumerate(inventory.arms)}
    received: list[list[int]] = []  # [arm index, sample number, receive time]
    with lock:
        for key, payload, now in raw:
            arm = space.parse_arm_key(key).arm
            joints = payloads.JOINTS.decode(payload)
            received.append([index[arm], marker_of(joints.angles_deg), now])
    return {"received": received}


def main() -> None:
    """``python -m bench.w_joints --inventory inv.toml``."""
    args = workerlib.parser(__doc__).parse_args()
    workerlib.emit(run(args.inventory, args.max_s))


if __name__ == "__main__":
    main()
