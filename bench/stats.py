"""Summaries of latency samples: median and p99 (nearest rank), in milliseconds."""

from __future__ import annotations

import math
from collections.abc import Sequence


def percentile(sorted_values: Sequence[float], q: float) -> float:
    """The nearest-rank ``q`` percentile (0 < q <= 100) of already sorted values."""
    if not sorted_values:
        return math.nan
    rank = max(1, math.ceil(q / 100.0 * len(sorted_values)))
    return float(sorted_values[rank - 1])


def summary_ms(samples_ns: Sequence[int | float]) -> dict[str, float]:
    """n, p50, p99, max of nanosecond samples, in milliseconds (3 decimals)."""
    values = sorted(float(v) / 1e6 for v in samples_ns)
    return {
        "n": len(values),
        "p50_ms": round(percentile(values, 50), 3),
        "p99_ms": round(percentile(values, 99), 3),
        "max_ms": round(values[-1], 3) if values else math.nan,
    }


def ratio(value: float, reference: float) -> float:
    """``value / reference`` rounded; NaN when the reference is missing or zero."""
    if not reference or math.isnan(reference) or math.isnan(value):
        return math.nan
    return round(value / reference, 2)
