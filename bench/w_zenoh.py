"""Worker: the raw Zenoh hop and fan-out, through the fleet's router, in client mode.

``pub`` puts ``count`` 100-byte payloads stamped with ``time.time_ns()``; ``sub`` runs
``--subs`` subscribers on the same key, each on a session of its own (one Zenoh subscriber per
session, as separate programs would be), and records per put the delay to the last of them.
"""

from __future__ import annotations

import threading
import time

import zenoh

from bench import workerlib
from fleet.client import STOP_QOS
from fleet.wire.session import open_client

KEY = "bench/raw/hop"
PAYLOAD_SIZE = 100


def stamped(index: int) -> bytes:
    """``"<index> <time_ns> "`` padded to 100 bytes."""
    return f"{index} {time.time_ns()} ".ljust(PAYLOAD_SIZE, "x").encode()


def run_pub(endpoints: list[str], count: int, warmup: int, rate_hz: float, stop_qos: bool) -> dict:
    """Put ``warmup + count`` stamped payloads at ``rate_hz`` (stop QoS: BLOCK, REAL_TIME)."""
    qos = STOP_QOS if stop_qos else {}
    with open_client(endpoints) as session:
        publisher = session.declare_publisher(KEY, **qos)  # type: ignore[arg-type]
        deadline = time.monotonic() + 10.0
        while not publisher.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.3)
        period = 1.0 / rate_hz
        next_s = time.monotonic()
        for index in range(warmup + count):
            publisher.put(stamped(index))
            next_s += period
            time.sleep(max(0.0, next_s - time.monotonic()))
        time.sleep(0.3)
        publisher.undeclare()
    return {"sent": warmup + count}


def run_sub(endpoints: list[str], subs: int, warmup: int, max_s: float) -> dict:
    """``subs`` sessions with one subscriber each; per put: [max delay ns, arrivals]."""
    lock = threading.Lock()
    last: dict[int, list[int]] = {}

    def on_sample(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        index, sent_ns, _ = sample.payload.to_bytes().split(b" ", 2)
        i = int(index)
        if i < warmup:
            return
        delay = now - int(sent_ns)
        with lock:
            entry = last.setdefault(i, [0, 0])
            entry[0] = max(entry[0], delay)
            entry[1] += 1

    sessions = [open_client(endpoints) for _ in range(subs)]
    subscribers = [s.declare_subscriber(KEY, on_sample) for s in sessions]
    done = workerlib.ready()
    done.wait(max_s)
    for subscriber in subscribers:
        subscriber.undeclare()
    for session in sessions:
        session.close()
    with lock:
        return {"subs": subs, "per_put": {str(k): v for k, v in last.items()}}


def main() -> None:
    """``python -m bench.w_zenoh pub|sub --inventory inv.toml ...``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("role", choices=["pub", "sub"])
    parser.add_argument("--subs", type=int, default=1)
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    parser.add_argument("--stop-qos", action="store_true")
    args = parser.parse_args()
    endpoints = workerlib.inventory(args).endpoints
    if args.role == "pub":
        result = run_pub(endpoints, args.count, args.warmup, args.rate_hz, args.stop_qos)
    else:
        result = run_sub(endpoints, args.subs, args.warmup, args.max_s)
    workerlib.emit(result)


if __name__ == "__main__":
    main()
