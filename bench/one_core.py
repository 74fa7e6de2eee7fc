"""Section ``onecore``: one agent core for every kind, measured against the layout it replaced.

- ``arm_and_gripper``: a simulated D1 (10 Hz) and the Dex1-1 mounted on it (500 Hz state from
  ``bench/w_grip.py``) served by one agent process (``edge-agent --arm a1 --device gl``), then by
  two (``--arm a1`` and ``--device gl``, the per-kind processes of before), in one run: the
  agents' CPU (sum over their processes, /proc) and the gripper's relayed rate.
- ``device_stop_under_flood``: stops of the gripper (its own ``estop`` key) while a process of
  its own floods the gripper's command key with undecodable queries as fast as it can; each
  stop timed from its ``stamp_ns`` to the agent's ``received_ns`` and ``dds_written_ns`` (the
  goal: at most 500 ms).
"""

from __future__ import annotations

import time
from typing import Any

from bench.proc import BenchFleet, cpu_s
from bench.stats import summary_ms
from fleet.client import FleetClient
from fleet.inventory import load_inventory

WARMUP_S = 3.0
DEVICE = "gl"
GRIPPER = f'[grippers.{DEVICE}]\nfamily = "go"\nmount = "a1"\nsimulated = false\n'


def _arm_and_gripper(agents: list[list[str]], window_s: float) -> dict[str, Any]:
    with BenchFleet(1, f"onecore{len(agents)}", extra=GRIPPER) as fleet:
        fleet.start_router()
        fleet.start("sim", ["-m", "fleet.cli.main", "sim", "--arm", "a1"])
        workers = [
            fleet.start(f"agent{i}", ["-m", "edge_agent", *argv]) for i, argv in enumerate(agents)
        ]
        feed = fleet.start(
            "grip", ["-m", "bench.w_grip", "--device", DEVICE, "--rate-hz", "500"], piped=True
        )
        feed.wait_ready(timeout_s=60.0)
        time.sleep(WARMUP_S)
        c0, t0, w0 = sum(cpu_s(w.pid) for w in workers), time.monotonic(), time.time_ns()
        time.sleep(window_s)
        c1, t1, w1 = sum(cpu_s(w.pid) for w in workers), time.monotonic(), time.time_ns()
        result = feed.finish()
    wall = t1 - t0
    relayed = sum(1 for _m, received_ns, _n in result["received"] if w0 <= received_ns < w1)
    return {
        "processes": len(agents),
        "window_s": round(wall, 1),
        "agent_cpu_pct": round(100.0 * (c1 - c0) / wall, 2),
        "gripper_zenoh_rate_hz": round(relayed / wall, 1),
    }


def arm_and_gripper(window_s: float) -> dict[str, Any]:
    """The same D1 + Dex1-1 load on one agent process and on two."""
    one = _arm_and_gripper([["--arm", "a1", "--device", DEVICE]], window_s)
    two = _arm_and_gripper([["--arm", "a1"], ["--device", DEVICE]], window_s)
    ratio = one["agent_cpu_pct"] / two["agent_cpu_pct"] if two["agent_cpu_pct"] else None
    return {"one": one, "two": two, "cpu_ratio_one_to_two": ratio and round(ratio, 3)}


def device_stop_under_flood(stops: int) -> dict[str, Any]:
    """Stops of a gripper whose command key is flooded by another process."""
    with BenchFleet(
        1, "devflood", extra=GRIPPER.replace("simulated = false", "simulated = true")
    ) as fleet:
        fleet.start_router()
        fleet.start("sim", ["-m", "fleet.cli.main", "sim"])
        fleet.start("agent", ["-m", "edge_agent", "--interface", "lo"])
        inventory = load_inventory(fleet.inventory)
        with FleetClient(inventory) as client:
            _wait_served(client)
            flood = fleet.start("flood", ["-m", "bench.w_flood", "--device", DEVICE], piped=True)
            flood.wait_ready(timeout_s=60.0)
            received, written = [], []
            for _ in range(stops):
                request = client.stop_request("bench: device stop under a flood", "bench")
                acks = client.estop(DEVICE, request=request, timeout_s=5.0, wait_still=False)
                ack = next(iter(acks.values()))
                if ack is not None:
                    received.append(ack.received_ns - request.stamp_ns)
                    if ack.dds_written_ns is not None:
                        written.append(ack.dds_written_ns - request.stamp_ns)
                client.reset(DEVICE)
                time.sleep(0.2)  # the reset acted on before the next stop (not a timing)
            sent = flood.finish()["sent"]
    return {
        "stops": stops,
        "flood_queries": sent,
        "received": summary_ms(received),
        "written": summary_ms(written),
    }


def _wait_served(client: FleetClient, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        reply = client.device_command(DEVICE, b'{"op": "hold"}')
        if reply.ok:
            return
        time.sleep(0.5)
    raise RuntimeError("the gripper was not served within 60 s")


def run(quick: bool) -> dict[str, Any]:
    """Both rows."""
    return {
        "arm_and_gripper": arm_and_gripper(8.0 if quick else 20.0),
        "device_stop_under_flood": device_stop_under_flood(10 if quick else 30),
    }
