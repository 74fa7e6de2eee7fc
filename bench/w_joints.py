"""Worker: a plain Zenoh subscriber on arms' ``joints`` (what any client of the key space sees).
The callback only stamps and stores; decoding happens after the run.

By default one subscriber on every arm (``arm/*/joints``); ``--every K`` subscribes to every
K-th arm only (one subscriber per arm key), so a client of a large fleet samples it without
becoming the bottleneck itself; ``--wait-all`` announces READY only once every subscribed arm
was heard (bounded by ``--max-s``).
"""

from __future__ import annotations

import argparse
import threading
import time

import zenoh

from bench import workerlib
from bench.w_feed import marker_of
from fleet.wire import keys, payloads
from fleet.wire.session import open_client


def run(args: argparse.Namespace) -> dict:
    """Record (key, payload, receive time) until stdin closes; then decode them."""
    inventory = workerlib.inventory(args)
    space = keys.KeySpace(inventory.fleet)
    index = {arm: i for i, arm in enumerate(inventory.arms)}
    lock = threading.Lock()
    raw: list[tuple[str, bytes, int]] = []
    heard = threading.Event()
    wanted = set(list(inventory.arms)[:: args.every]) if args.wait_all else set()

    def on_sample(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        item = (str(sample.key_expr), sample.payload.to_bytes(), now)
        with lock:
            raw.append(item)
            if wanted:
                wanted.discard(space.parse_arm_key(item[0]).arm)
                if not wanted:
                    heard.set()

    with open_client(inventory.endpoints) as session:
        if args.every == 1:
            key_exprs = [space.all_arms(keys.JOINTS)]
        else:
            key_exprs = [space.arm(a, keys.JOINTS) for a in list(inventory.arms)[:: args.every]]
        subscribers = [session.declare_subscriber(k, on_sample) for k in key_exprs]
        if args.wait_all:
            heard.wait(args.max_s)
            with lock:
                raw.clear()  # the run starts now
                missing = len(wanted)
        else:
            missing = 0
        done = workerlib.ready()
        done.wait(args.max_s)
        for subscriber in subscribers:
            subscriber.undeclare()
    received: list[list[int]] = []  # [arm index, marker, receive time, joints stamp_ns]
    with lock:
        for key, payload, now in raw:
            arm = space.parse_arm_key(key).arm
            joints = payloads.JOINTS.decode(payload)
            received.append([index[arm], marker_of(joints.angles_deg), now, joints.stamp_ns])
    arms = len(list(inventory.arms)[:: args.every])
    return {"received": received, "arms": arms, "never_heard": missing}


def main() -> None:
    """``python -m bench.w_joints --inventory inv.toml [--every K] [--wait-all]``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("--every", type=int, default=1, help="only every K-th arm")
    parser.add_argument("--wait-all", action="store_true", help="READY once all were heard")
    args = parser.parse_args()
    workerlib.emit(run(args))


if __name__ == "__main__":
    main()
