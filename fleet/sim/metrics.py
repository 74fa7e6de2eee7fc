"""The simulator's Prometheus collectors (read at scrape time)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from fleet.metrics import FunctionCollector, counter, gauge

if TYPE_CHECKING:
    from fleet.sim.node import SimulatedArms


def sim_collectors(sim: SimulatedArms) -> list[Any]:
    """Reports served, the achieved rate per arm and the worst lateness."""

    def collect() -> list[Any]:
        reports, arms, elapsed_s, late_s = sim.stats()
        arms = max(1, arms)
        return [
            counter("d1_sim_reports", "angle reports published (all arms)", [], [([], reports)]),
            gauge(
                "d1_sim_feedback_rate_hz",
                "angle reports per arm and second since the start",
                [],
                [([], reports / arms / max(elapsed_s, 1e-9))],
            ),
            gauge("d1_sim_late_max_seconds", "worst lateness of a report", [], [([], late_s)]),
        ]

    return [FunctionCollector(collect)]
