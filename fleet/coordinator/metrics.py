"""The coordinator's Prometheus collectors: its diag counters and fleet state at scrape time,
and stop latencies from its own stop reports (a subscriber on ``estop/report`` whose callback
only appends to a bounded deque)."""

from __future__ import annotations

import collections
import logging
import time
from typing import TYPE_CHECKING, Any

import zenoh

from fleet.metrics import FunctionCollector, LatencySink, counter, gauge
from fleet.wire import payloads

if TYPE_CHECKING:
    from fleet.coordinator.service import Coordinator

log = logging.getLogger("fleet.coordinator")

STEPS = ("received", "dds_written", "still")
SEEN_LIMIT = 4096


def coordinator_collectors(coordinator: Coordinator) -> list[Any]:
    """Counters, arms online, and stop latency histograms per step (stamp -> received,
    -> DDS written, -> still), each arm's step counted once per stop."""
    sinks = {step: LatencySink() for step in STEPS}
    last_sinks = {step: LatencySink() for step in STEPS}
    seen: collections.OrderedDict[tuple[str, str, str], None] = collections.OrderedDict()
    fleet_arms = frozenset(coordinator.inventory.arms)

    def on_report(sample: zenoh.Sample) -> None:
        try:
            report = payloads.STOP_REPORT.decode(sample.payload.to_bytes())
        except payloads.PayloadError:
            return  # not ours to count: the coordinator's own intake counts bad samples
        for arm, timing in report.arms.items():
            for step in STEPS:
                value = getattr(timing, f"{step}_ms")
                key = (report.stop_id, arm, step)
                if value is None or key in seen:
                    continue
                seen[key] = None
                if len(seen) > SEEN_LIMIT:
                    seen.popitem(last=False)
                sinks[step].add(value / 1000.0)
        # A fleet-wide figure (issue 24): once every arm of the inventory reported a step of
        # this stop, its slowest arm's time, counted once per stop and step.
        if not fleet_arms or not fleet_arms <= report.arms.keys():
            return
        for step in STEPS:
            values = [getattr(report.arms[a], f"{step}_ms") for a in fleet_arms]
            key = (report.stop_id, "*", step)
            if any(v is None for v in values) or key in seen:
                continue
            seen[key] = None
            slowest = max(fleet_arms, key=lambda a: getattr(report.arms[a], f"{step}_ms"))
            last_sinks[step].add(max(v for v in values if v is not None) / 1000.0)
            if step == "still":
                log.info(
                    "stop %s: every arm still after %.0f ms, the last %s",
                    report.stop_id[:24],
                    max(v for v in values if v is not None),
                    slowest,
                )

    # Kept by the collector; undeclared with the session when the coordinator closes.
    subscriber = coordinator.session.declare_subscriber(coordinator.keys.stop_report, on_report)

    def collect() -> list[Any]:
        diag = coordinator.diag(time.time_ns())
        now = time.monotonic()
        with coordinator.lock:
            online = [(a, coordinator.state.online(a, now)) for a in coordinator.inventory.arms]
        metrics: list[Any] = [
            counter("d1_coordinator_bad_events", "undecodable events", [], [([], diag.bad_events)]),
            counter(
                "d1_coordinator_unknown_arms",
                "events of unknown arms",
                [],
                [([], diag.unknown_arms)],
            ),
            counter(
                "d1_coordinator_dropped_events",
                "events dropped at a full queue",
                [],
                [([], diag.dropped_events)],
            ),
            counter(
                "d1_coordinator_busy", "multi-arm requests answered busy", [], [([], diag.busy)]
            ),
            counter(
                "d1_coordinator_bad_keys",
                "multi-arm requests on a key naming no principal",
                [],
                [([], diag.bad_keys)],
            ),
            gauge(
                "d1_coordinator_requests_active",
                "multi-arm requests being served",
                [],
                [([], diag.requests_active)],
            ),
            gauge(
                "d1_coordinator_arm_online",
                "1 while the arm's agent is heard",
                ["arm"],
                [([a], ok) for a, ok in online],
            ),
        ]
        for step in STEPS:
            metrics.append(
                sinks[step].family(
                    f"d1_stop_{step}_latency_seconds",
                    f"from a stop's stamp to its {step.replace('_', ' ')} on an arm",
                )
            )
            metrics.append(
                last_sinks[step].family(
                    f"d1_stop_last_arm_{step}_latency_seconds",
                    f"from a stop's stamp to its {step.replace('_', ' ')} on the last arm of "
                    "the fleet (each stop every arm reported)",
                )
            )
        return metrics

    collector = FunctionCollector(collect)
    collector.subscriber = subscriber
    return [collector]
