"""Sections 3 and 4: command round trip and stop fan-out on a real fleet (router, ``fleet sim``,
edge agents) of separate processes on loopback."""

from __future__ import annotations

import math
from typing import Any

from bench.proc import BenchFleet
from bench.stats import summary_ms

ARMS_PER_AGENT = 25
"""Stop fan-out: agents serve up to this many arms each (4 agent processes for 100 arms)."""


def command_rtt(count: int) -> dict[str, Any]:
    """``FleetClient.command`` round trips to one simulated arm."""
    with BenchFleet(1, "cmd") as fleet:
        fleet.start_router()
        fleet.start("sim", ["-m", "fleet.cli.main", "sim"])
        fleet.start("agent", ["-m", "edge_agent", *fleet.arm_args(fleet.arms)])
        client = fleet.start("client", ["-m", "bench.w_cmd", "--count", str(count)], piped=True)
        client.wait_ready(timeout_s=90.0)
        result = client.result(timeout_s=60.0 + count * 0.5)
    agent = sorted(result["agent_latency_ms"])
    return {
        **summary_ms(result["rtt_ns"]),
        "agent_p50_ms": agent[len(agent) // 2] if agent else math.nan,
        "failures": result["failures"],
    }


def stop_fanout(arms: int, stops: int) -> dict[str, Any]:
    """Fleet stops to ``arms`` simulated arms (one ``fleet sim`` process, agents grouped)."""
    with BenchFleet(arms, f"stop{arms}") as fleet:
        fleet.start_router()
        fleet.start("sim", ["-m", "fleet.cli.main", "sim"])
        groups = fleet.groups(ARMS_PER_AGENT)
        for i, group in enumerate(groups):
            fleet.start(f"agent{i}", ["-m", "edge_agent", *fleet.arm_args(group)])
        return {"agents": len(groups), **stops_run(fleet, stops)}


def stops_run(fleet: BenchFleet, stops: int, timeout_s: float = 5.0) -> dict[str, Any]:
    """``stops`` fleet stops by ``bench.w_stop`` on a running fleet: the time from each stop's
    stamp to the last arm's ack (received, DDS written), over the stops every arm acked."""
    argv = ["-m", "bench.w_stop", "--stops", str(stops), "--timeout-s", str(timeout_s)]
    client = fleet.start("stopper", argv + ["--seen-timeout-s", "120"], piped=True)
    client.wait_ready(timeout_s=150.0)
    result = client.result(timeout_s=60.0 + stops * (timeout_s + 2.0))
    complete = [s for s in result["stops"] if s["missing"] == 0]
    return {
        "arms": result["arms"],
        "arms_seen": result["seen"],
        "stops": len(result["stops"]),
        "incomplete_stops": len(result["stops"]) - len(complete),
        "most_missing": max((s["missing"] for s in result["stops"]), default=0),
        "fewest_answering": min((s["answered"] for s in result["stops"]), default=0),
        "last_written": summary_ms([s["last_written_ns"] for s in complete]),
        "last_received": summary_ms([s["last_received_ns"] for s in complete]),
    }


def run(quick: bool) -> dict[str, Any]:
    """Command round trip and stop fan-out at 10, 50 and 100 arms."""
    stops = 6 if quick else 20
    return {
        "command": command_rtt(60 if quick else 300),
        **{f"stop_{n}": stop_fanout(n, stops) for n in (10, 50, 100)},
    }
