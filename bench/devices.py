"""Section ``devices``: one Dex1-1's state at 500 Hz through the agent; a G1's rt/arm_sdk
stream at 50 Hz: its jitter at a lightweight receiver.

Processes: router, ``edge-agent --device gl`` (the agent serving the gripper, nothing else) and
``bench/w_grip.py`` (the gripper's DDS state stream and a plain Zenoh subscriber on its state).
CPU of the agent from /proc over a window after a warm-up, per DDS sample written in the
window, and per thread (``dev-relay`` is ours; ``recv`` is CycloneDDS receiving the packets,
``tx-*``/``net-*`` Zenoh's); latency from the send time of the DDS sample a relayed state
carries to its arrival on Zenoh, at the configured relay rate (each relayed state carries the
newest sample).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from bench.proc import CLOCK_TICKS, BenchFleet, cpu_s
from bench.stats import summary_ms
from bench.w_grip import MARK_MOD
from fleet.g1.arms import PERIOD_S

WARMUP_S = 3.0


def thread_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds of each thread of ``pid`` by thread name (summed over equal names)."""
    out: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended
            continue
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / CLOCK_TICKS
    return out


DEVICE = "gl"


def gripper_run(rate_hz: float, relay_hz: float, window_s: float) -> dict[str, Any]:
    """One gripper at ``rate_hz`` relayed at ``relay_hz``: agent CPU and latency."""
    extra = f'[grippers.{DEVICE}]\nfamily = "go"\nrelay_hz = {relay_hz}\nsimulated = false\n'
    with BenchFleet(1, f"grip{rate_hz:g}", extra=extra) as fleet:
        fleet.start_router()
        agent = fleet.start("devices", ["-m", "edge_agent", "--device", DEVICE])
        feed = fleet.start(
            "grip", ["-m", "bench.w_grip", "--device", DEVICE, "--rate-hz", str(rate_hz)],
            piped=True,
        )  # fmt: skip
        feed.wait_ready(timeout_s=60.0)
        time.sleep(WARMUP_S)
        c0, t0, w0 = cpu_s(agent.pid), time.monotonic(), time.time_ns()
        threads0 = thread_cpu_s(agent.pid)
        time.sleep(window_s)
        c1, t1, w1 = cpu_s(agent.pid), time.monotonic(), time.time_ns()
        threads1 = thread_cpu_s(agent.pid)
        result = feed.finish()
    sent: list[int] = result["sent_ns"]
    in_window = sum(1 for ns in sent if w0 <= ns < w1)
    delays = []
    relayed = 0
    for marker, received_ns, _dds_samples in result["received"]:
        if not w0 <= received_ns < w1:
            continue
        relayed += 1
        # The newest sample sent before the state arrived with this marker.
        sent_before = (i for i in range(marker, len(sent), MARK_MOD) if sent[i] <= received_ns)
        k = max(sent_before, default=-1)
        if k >= 0:
            delays.append(received_ns - sent[k])
    wall = t1 - t0
    cpu = c1 - c0
    threads = {
        name: round(100.0 * (spent - threads0.get(name, 0.0)) / wall, 2)
        for name, spent in threads1.items()
        if spent - threads0.get(name, 0.0) > 0
    }
    return {
        "rate_hz": rate_hz,
        "relay_hz": relay_hz,
        "window_s": round(wall, 1),
        "matched": result["matched"],
        "dds_samples": in_window,
        "dds_rate_hz": round(in_window / wall, 1),
        "zenoh_rate_hz": round(relayed / wall, 1),
        "latency": summary_ms(delays),
        "agent_cpu_pct": round(100.0 * cpu / wall, 2),
        "agent_cpu_us_per_sample": round(cpu / max(1, in_window) * 1e6, 1),
        "agent_threads_pct": dict(sorted(threads.items(), key=lambda kv: -kv[1])),
    }


G1 = "h1"
ARM_SDK_GOAL_P99_MS = 5.0
"""Issue 23: rt/arm_sdk jitter p99 (|gap - 20 ms| between consecutive messages) at most this."""


def arm_sdk_run(window_s: float) -> dict[str, Any]:
    """The agent's rt/arm_sdk stream to the simulated G1 (``fleet sim``), received by
    ``bench/w_armsdk.py`` (a bare DDS reader stamping arrivals) while it keeps the arms
    engaged: the gaps between consecutive messages at full weight, and their jitter."""
    extra = f"[g1.{G1}]\nsim_settle_s = 0.1\n"
    with BenchFleet(1, "armsdk", extra=extra) as fleet:
        fleet.start_router()
        fleet.start("sim", ["-m", "fleet.cli.main", "sim"])
        agent = fleet.start("agent", ["-m", "edge_agent", "--device", G1])
        recv = fleet.start("armsdk", ["-m", "bench.w_armsdk", "--device", G1], piped=True)
        recv.wait_ready(timeout_s=60.0)
        time.sleep(WARMUP_S)  # discovery, the first target, the 1 s engage ramp
        c0, t0, m0 = cpu_s(agent.pid), time.monotonic(), time.monotonic_ns()
        time.sleep(window_s)
        c1, t1, m1 = cpu_s(agent.pid), time.monotonic(), time.monotonic_ns()
        result = recv.finish()
    arrivals = [(ns, w) for ns, w in result["arrivals"] if m0 <= ns < m1]
    gaps = [b[0] - a[0] for a, b in zip(arrivals, arrivals[1:]) if a[1] >= 1.0 and b[1] >= 1.0]
    period_ns = PERIOD_S * 1e9
    jitter = summary_ms([abs(g - period_ns) for g in gaps])
    wall = t1 - t0
    return {
        "window_s": round(wall, 1),
        "messages": len(arrivals),
        "rate_hz": round(len(arrivals) / wall, 1),
        "gap": summary_ms(gaps),
        "jitter": jitter,
        "goal_p99_ms": ARM_SDK_GOAL_P99_MS,
        "goal_met": bool(gaps) and jitter["p99_ms"] <= ARM_SDK_GOAL_P99_MS,
        "agent_cpu_pct": round(100.0 * (c1 - c0) / wall, 2),
        "refused": result["refused"],
    }


def run(quick: bool) -> dict[str, Any]:
    """One gripper at 500 Hz relayed at the default 50 Hz; a G1's rt/arm_sdk at 50 Hz."""
    return {
        "gripper_500": gripper_run(500.0, 50.0, 8.0 if quick else 20.0),
        "g1_arm_sdk_50": arm_sdk_run(8.0 if quick else 20.0),
    }
