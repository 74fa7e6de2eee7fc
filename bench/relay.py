"""Sections 2, 5 and 6: relay latency and the cost of relaying, at 1, 10 and 100 arms.

Processes: router, coordinator, one edge agent serving every arm, a simulated-arm-like
feedback writer (bench/w_feed.py) and a plain subscriber on ``arm/*/joints`` (bench/w_joints.py).
Latency is the feedback's send time (just before the DDS write) to the subscriber's callback.
CPU comes from /proc over a window after a warm-up; the agent's per-message figure divides its
CPU by the feedback samples written in the window (every one is relayed as raw/feedback and
joints; its status, diag and housekeeping are part of the cost).
"""

from __future__ import annotations

import time
from typing import Any

from bench.proc import BenchFleet, Worker, cpu_s, rss_mb
from bench.stats import summary_ms

WARMUP_S = 3.0


def _cpu(workers: dict[str, Worker]) -> dict[str, float]:
    return {name: cpu_s(w.pid) for name, w in workers.items()}


def relay_run(arms: int, rate_hz: float, window_s: float) -> dict[str, Any]:
    """One fleet of ``arms`` arms at ``rate_hz``: latency, CPU and memory over ``window_s``."""
    with BenchFleet(arms, f"relay{arms}x{rate_hz:g}") as fleet:
        router = fleet.start_router()
        coordinator = fleet.start("coordinator", ["-m", "fleet.cli.main", "coordinator"])
        agent = fleet.start("agent", ["-m", "edge_agent", *fleet.arm_args(fleet.arms)])
        sub = fleet.start("joints-sub", ["-m", "bench.w_joints"], piped=True)
        sub.wait_ready()
        feed = fleet.start("feed", ["-m", "bench.w_feed", "--rate-hz", str(rate_hz)], piped=True)
        feed.wait_ready(timeout_s=90.0)
        time.sleep(WARMUP_S)
        watched = {"agent": agent, "coordinator": coordinator, "router": router}
        rss0 = rss_mb(coordinator.pid)
        c0, t0, w0 = _cpu(watched), time.monotonic(), time.time_ns()
        time.sleep(window_s)
        c1, t1, w1 = _cpu(watched), time.monotonic(), time.time_ns()
        rss1 = rss_mb(coordinator.pid)
        fed = feed.finish()
        time.sleep(0.5)  # the last samples of the feed reach the subscriber
        got = sub.finish()
    sent: list[list[int]] = fed["sent_ns"]
    in_window = sum(1 for per_arm in sent for ns in per_arm if w0 <= ns < w1)
    delays = []
    lost = 0
    received = {(a, k): ns for a, k, ns, _stamp in got["received"]}
    for a, per_arm in enumerate(sent):
        for k, ns in enumerate(per_arm):
            if not w0 <= ns < w1:
                continue
            if (a, k) in received:
                delays.append(received[(a, k)] - ns)
            else:
                lost += 1
    wall = t1 - t0
    cpu = {name: c1[name] - c0[name] for name in watched}
    return {
        "arms": arms,
        "rate_hz": rate_hz,
        "window_s": round(wall, 1),
        "matched_writers": fed["matched"],
        "latency": {**summary_ms(delays), "lost": lost},
        "messages": in_window,
        "agent_cpu_us_per_msg": round(cpu["agent"] / max(1, in_window) * 1e6, 1),
        "agent_cpu_pct": round(100.0 * cpu["agent"] / wall, 2),
        "coordinator_cpu_pct": round(100.0 * cpu["coordinator"] / wall, 2),
        "router_cpu_pct": round(100.0 * cpu["router"] / wall, 2),
        "coordinator_rss_mb": [round(rss0, 1), round(rss1, 1)],
    }


def run(quick: bool) -> dict[str, Any]:
    """Relay latency at 10 and 100 Hz (1 arm) and the cost at 1, 10 and 100 arms at 10 Hz."""
    short, long = (6.0, 10.0) if quick else (15.0, 45.0)
    return {
        "1x10": relay_run(1, 10.0, short),
        "1x100": relay_run(1, 100.0, short),
        "10x10": relay_run(10, 10.0, short),
        "100x10": relay_run(100, 10.0, long),
    }
