"""Worker: command round trips through the public API (``FleetClient.command``: a Zenoh query
on ``arm/<arm>/cmd`` -> agent -> DDS -> simulated arm's receive and execute acks -> reply)."""

from __future__ import annotations

import time

from bench import workerlib
from fleet.client import FleetClient
from fleet.wire import messages as m


def run(args_inventory: str, count: int, warmup: int) -> dict:
    """Wait for the arm's link, then time ``count`` small single-joint moves one by one."""
    inventory = workerlib.load_inventory(args_inventory)
    arm = next(iter(inventory.arms))
    rtts: list[int] = []
    agent_ms: list[float] = []
    failures: list[str] = []
    with FleetClient(inventory) as client:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            status, _joints = client.snapshot([arm], wait_s=1.0)[arm]
            if status is not None and status.link == "ok":
                break
        workerlib.ready()
        for i in range(warmup + count):
            command = m.MoveJoint(joint=0, angle_deg=1.0 if i % 2 else -1.0)
            t0 = time.perf_counter_ns()
            reply = client.command(arm, command)
            t1 = time.perf_counter_ns()
            if not reply.ok:
                failures.append(reply.error.message if reply.error else "not ok")
            elif i >= warmup:
                rtts.append(t1 - t0)
                agent_ms.append(reply.latency_ms)
            time.sleep(0.01)
    return {"rtt_ns": rtts, "agent_latency_ms": agent_ms, "failures": failures[:5]}


def main() -> None:
    """``python -m bench.w_cmd --inventory inv.toml --count 300``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("--count", type=int, default=300)
    parser.add_argument("--warmup", type=int, default=20)
    args = parser.parse_args()
    workerlib.emit(run(args.inventory, args.count, args.warmup))


if __name__ == "__main__":
    main()
