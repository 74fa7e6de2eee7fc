"""Section 1: the raw limits of this machine, measured in the same run as the fleet.

One DDS hop (writer process -> reader process), one Zenoh hop (publisher -> router ->
subscriber, three processes) and a Zenoh fan-out of one put to N subscribers spread over a few
processes (each subscriber a session of its own).
"""

from __future__ import annotations

import math
from typing import Any

from bench.proc import BenchFleet
from bench.stats import summary_ms

SUBS_PER_PROCESS = 25


def dds_hop(count: int, rate_hz: float = 100.0) -> dict[str, Any]:
    """One-way delay of a feedback-sized ArmString_ between two processes."""
    with BenchFleet(0, "dds") as fleet:
        domain = ["--domain", str(fleet.domain)]
        reader = fleet.start("dds-reader", ["-m", "bench.w_dds", "reader", *domain], piped=True)
        reader.wait_ready()
        writer = fleet.start(
            "dds-writer",
            ["-m", "bench.w_dds", "writer", *domain, "--count", str(count)]
            + ["--rate-hz", str(rate_hz)],
            piped=True,
        )
        sent = writer.result(timeout_s=count / rate_hz + 60.0)["sent"]
        got = reader.finish()
    delays = got["delays_ns"]
    return {**summary_ms(delays), "sent": sent, "received": got["received"], "samples_ns": delays}


def zenoh_fanout(subscribers: int, count: int, rate_hz: float, stop_qos: bool) -> dict[str, Any]:
    """Delay from one put to its arrival at the last of ``subscribers`` (through the router)."""
    with BenchFleet(0, f"zenoh{subscribers}") as fleet:
        fleet.start_router()
        return fanout_in(fleet, subscribers, count, rate_hz, stop_qos)


def fanout_in(
    fleet: BenchFleet,
    subscribers: int,
    count: int,
    rate_hz: float,
    stop_qos: bool,
    pub_endpoint: str | None = None,
) -> dict[str, Any]:
    """``zenoh_fanout`` on the routers of ``fleet``: subscribers on its inventory's router, the
    publisher there too or on ``pub_endpoint`` (another router joined to it)."""
    processes = max(1, math.ceil(subscribers / SUBS_PER_PROCESS))
    shares = [subscribers // processes + (i < subscribers % processes) for i in range(processes)]
    subs = [
        fleet.start(f"sub{i}", ["-m", "bench.w_zenoh", "sub", "--subs", str(n)], piped=True)
        for i, n in enumerate(shares)
    ]
    for sub in subs:
        sub.wait_ready()
    pub_argv = ["-m", "bench.w_zenoh", "pub", "--count", str(count), "--rate-hz", str(rate_hz)]
    pub_argv += ["--stop-qos"] if stop_qos else []
    pub_argv += ["--endpoint", pub_endpoint] if pub_endpoint else []
    pub = fleet.start("pub", pub_argv, piped=True)
    pub.result(timeout_s=count / rate_hz + 60.0)
    results = [sub.finish() for sub in subs]
    for worker in (pub, *subs):
        worker.stop()
    worst: dict[str, int] = {}
    arrivals: dict[str, int] = {}
    for result in results:
        for index, (delay, n) in result["per_put"].items():
            worst[index] = max(worst.get(index, 0), delay)
            arrivals[index] = arrivals.get(index, 0) + n
    complete = [worst[i] for i in worst if arrivals[i] == subscribers]
    return {
        **summary_ms(complete),
        "samples_ns": complete,
        "subscribers": subscribers,
        "processes": processes,
        "puts": count,
        "incomplete_puts": count - len(complete),
    }


def hops(quick: bool) -> dict[str, Any]:
    """One DDS hop and one Zenoh hop (run at the start and again at the end of the bench)."""
    count = 300 if quick else 800
    return {"dds_hop": dds_hop(count), "zenoh_hop": zenoh_fanout(1, count, 100.0, stop_qos=False)}


def fanouts(quick: bool) -> dict[str, Any]:
    """Fan-out of one put (stop QoS) to 10, 50 and 100 subscribers."""
    count = 40 if quick else 150
    return {f"zenoh_fanout_{n}": zenoh_fanout(n, count, 20.0, stop_qos=True) for n in (10, 50, 100)}


def pooled(first: dict[str, Any], second: dict[str, Any]) -> dict[str, Any]:
    """The two repetitions of one raw hop as one summary over all their samples."""
    samples = first.pop("samples_ns") + second.pop("samples_ns")
    return {**summary_ms(samples), "repeats": [first, second]}
