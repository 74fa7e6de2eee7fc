"""Worker: fleet-wide stops put on ``fleet/<fleet>/estop`` (stop QoS, like ``fleet estop``),
timed from the stop's ``stamp_ns`` to each arm's StopAck (``received_ns``, ``dds_written_ns``);
a ``FleetClient.reset`` between stops."""

from __future__ import annotations

import threading
import time
import uuid

import zenoh

from bench import workerlib
from fleet.client import STOP_QOS, FleetClient
from fleet.inventory import Inventory
from fleet.wire import keys, payloads
from fleet.wire import messages as m

SETTLE_S = 0.6
"""After a reset: the agents release the latch and write a hold before the next stop."""


def run(inventory: Inventory, stops: int, timeout_s: float, seen_timeout_s: float) -> dict:
    """Wait until every arm relays joints, then stop and reset ``stops`` times."""
    space = keys.KeySpace(inventory.fleet)
    arms = set(inventory.arms)
    lock = threading.Lock()
    seen: set[str] = set()
    acks: dict[str, m.StopAck] = {}
    answered: set[str] = set()  # arms that acked the current stop at all (written or not yet)
    current = [""]

    def on_joints(sample: zenoh.Sample) -> None:
        with lock:
            seen.add(space.parse_arm_key(str(sample.key_expr)).arm)

    def on_ack(sample: zenoh.Sample) -> None:
        ack = payloads.STOP_ACK.decode(sample.payload.to_bytes())
        with lock:
            if ack.stop_id == current[0]:
                answered.add(ack.arm)
            if ack.stop_id == current[0] and ack.arm not in acks and ack.dds_written_ns:
                acks[ack.arm] = ack

    results: list[dict[str, float | int]] = []
    with FleetClient(inventory) as client:
        session = client.session
        subs = [
            session.declare_subscriber(space.all_arms(keys.JOINTS), on_joints),
            session.declare_subscriber(space.all_arms(keys.ESTOP_ACK), on_ack),
        ]
        deadline = time.monotonic() + seen_timeout_s
        while time.monotonic() < deadline and len(seen) < len(arms):
            time.sleep(0.1)
        subs.pop(0).undeclare()  # every arm relays: its 10 Hz joints would only load us now
        workerlib.ready()
        time.sleep(1.0)
        for _ in range(stops):
            stop_id = uuid.uuid4().hex
            with lock:
                current[0] = stop_id
                acks.clear()
                answered.clear()
            request = m.StopRequest(time.time_ns(), "bench", stop_id, "benchmark")
            session.put(space.estop, m.encode(request), **STOP_QOS)  # type: ignore[arg-type]
            end = time.monotonic() + timeout_s
            while time.monotonic() < end:
                with lock:
                    if len(acks) == len(arms):
                        break
                time.sleep(0.002)
            with lock:
                got = list(acks.values())
                results.append(
                    {**_timing(request.stamp_ns, got, len(arms)), "answered": len(answered)}
                )
            client.reset(source="bench")
            time.sleep(SETTLE_S)
        for sub in subs:
            sub.undeclare()
    return {"arms": len(arms), "seen": len(seen), "stops": results}


def _timing(stamp_ns: int, acks: list[m.StopAck], arms: int) -> dict[str, float | int]:
    """Time to the last arm's receipt and DDS write (ns after the stop's stamp)."""
    return {
        "acked": len(acks),
        "missing": arms - len(acks),
        "last_received_ns": max((a.received_ns - stamp_ns for a in acks), default=-1),
        "last_written_ns": max((a.dds_written_ns or 0) - stamp_ns for a in acks) if acks else -1,
    }


def main() -> None:
    """``python -m bench.w_stop --inventory inv.toml --stops 20``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("--stops", type=int, default=20)
    parser.add_argument("--timeout-s", type=float, default=5.0)
    parser.add_argument("--seen-timeout-s", type=float, default=90.0, help="for every arm")
    args = parser.parse_args()
    inventory = workerlib.inventory(args)
    workerlib.emit(run(inventory, args.stops, args.timeout_s, args.seen_timeout_s))


if __name__ == "__main__":
    main()
