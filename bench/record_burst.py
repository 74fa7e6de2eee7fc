"""Joints lost under a burst: ``fleet record`` against an independent plain subscriber.

``python -m bench.record_burst [--arms 3] [--rate 1000] [--seconds 3] [--busy 0]`` starts a
router, a plain Zenoh subscriber process that only counts ``seq`` (the reference: what any
client of the key space receives), and ``fleet record``; this process then publishes every
arm's joints with congestion control DROP, like the agent, at ``--rate`` Hz per arm (0: as fast
as it can) and prints, per arm, the samples missing by seq at the reference and at the
recorder. Loss at both is upstream (the publisher's or the router's queues); loss only at the
recorder is the recorder's own. ``--busy N`` adds N processes spinning on the CPU.
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgspec
import zenoh

from fleet.record.gaps import SeqGaps
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.session import open_client
from testkit.harness import FleetHarness, wait_until

FLEET = "test"  # the harness inventory's fleet name


def counter(endpoint: str, out: str) -> None:
    """The reference subscriber: count seq per arm until stdin closes."""
    space = keys.KeySpace(FLEET)
    seen: list[tuple[str, bytes]] = []
    with open_client([endpoint]) as session:
        sub = session.declare_subscriber(
            space.all_arms(keys.JOINTS),
            lambda s: seen.append((str(s.key_expr), s.payload.to_bytes())),
        )
        print("READY", flush=True)
        sys.stdin.read()
        time.sleep(0.5)  # what is still on its way
        sub.undeclare()
    gaps = SeqGaps()
    for key, data in list(seen):
        gaps.add(space.parse_arm_key(key).arm, payloads.JOINTS.decode(data).seq)
    result = {arm: [g.received, g.missing] for arm, g in gaps.arms.items()}
    Path(out).write_text(json.dumps(result))


def publish(endpoint: str, arms: int, rate_hz: float, seconds: float) -> tuple[int, float]:
    """Joints of ``arms`` arms (seq from 1), DROP like the agent; (samples per arm, seconds)."""
    space = keys.KeySpace(FLEET)
    encoder = msgspec.json.Encoder()
    with open_client([endpoint]) as session:
        pubs = [
            session.declare_publisher(
                space.arm(f"a{i}", keys.JOINTS), congestion_control=zenoh.CongestionControl.DROP
            )
            for i in range(1, arms + 1)
        ]
        wait_until(lambda: all(p.matching_status.matching for p in pubs), 10.0)
        time.sleep(0.5)  # both subscribers' declarations reached the router
        count = int((rate_hz or 10000) * seconds)
        started = time.monotonic()
        for seq in range(1, count + 1):
            if rate_hz:
                delay = started + seq / rate_hz - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            for i, pub in enumerate(pubs, start=1):
                pub.put(encoder.encode(m.Joints(time.time_ns(), [float(i)] * 7, seq)))
        took = time.monotonic() - started
        time.sleep(0.5)
    return count, took


def main() -> None:
    """Run one burst and print the table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--arms", type=int, default=3)
    parser.add_argument("--rate", type=float, default=1000.0, help="Hz per arm; 0 = flat out")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--busy", type=int, default=0, help="CPU-spinning processes")
    parser.add_argument("--counter", nargs=2, metavar=("ENDPOINT", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.counter:
        counter(*args.counter)
        return
    spinners = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)
    ]
    try:
        with tempfile.TemporaryDirectory() as tmp, FleetHarness(Path(tmp), args.arms) as h:
            h.start_router()
            out = Path(tmp) / "counter.json"
            ref = subprocess.Popen(
                [sys.executable, "-m", "bench.record_burst", "--counter", h.endpoint, str(out)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
            assert ref.stdout is not None and ref.stdin is not None
            assert ref.stdout.readline().strip() == "READY"
            h.start("record", ["-m", "fleet.cli.main", "record", "-o", f"{tmp}/b.mcap"])
            wait_until(lambda: "recording " in h.log("record"), 15.0)
            count, took = publish(h.endpoint, args.arms, args.rate, args.seconds)
            ref.stdin.close()
            ref.wait(timeout=30)
            h.stop("record", sig=signal.SIGINT, timeout_s=30)
            log = h.log("record")
            reference = json.loads(out.read_text())
    finally:
        for spinner in spinners:
            spinner.kill()
            spinner.wait()
    print(f"{args.arms} arms x {count} samples in {took:.2f} s ({args.arms * count / took:.0f}/s)")
    print(f"busy processes: {args.busy}")
    dropped = re.search(r"(\d+) dropped", log)
    print(f"recorder queue overflow ('dropped'): {dropped.group(1) if dropped else '?'}")
    print(f"per arm, of {count} published: received (missing by seq)")
    print("arm   reference subscriber   fleet record")
    for i in range(1, args.arms + 1):
        arm = f"a{i}"
        got = re.search(rf"{arm}: (\d+) received, (\d+) missing", log)
        rec = f"{got.group(1)} ({got.group(2)})" if got else "none"
        received, missing = reference.get(arm, [0, 0])
        print(f"{arm:5} {received:>10} ({missing}){'':8} {rec}")


if __name__ == "__main__":
    main()
