"""The detection methods as pure functions of one joint's recent samples.

Each returns whether it *fires* on the newest sample; temporal confirmation (firing
continuously for ``confirm_s``) and the state machine live in ``detector.py``.
"""

from __future__ import annotations

from collections import deque

from fleet.contact.config import Thresholds

Samples = deque[tuple[float, float]]
"""(time s, measured angle deg), oldest first."""


def tracking(error_deg: float, t: Thresholds) -> bool:
    """Method 1: the tracking error is above the confirming threshold."""
    return abs(error_deg) > t.confirm_deg


def velocity_deg_s(samples: Samples) -> float | None:
    """Speed over the last feedback interval (None with fewer than two samples)."""
    if len(samples) < 2:
        return None
    (t0, a0), (t1, a1) = samples[-2], samples[-1]
    if t1 <= t0:
        return None
    return (a1 - a0) / (t1 - t0)


def stall(error_deg: float, samples: Samples, t: Thresholds) -> bool:
    """Method 2 (with 1): error above ``stall_error_deg`` while the joint is (nearly) still."""
    velocity = velocity_deg_s(samples)
    return (
        velocity is not None
        and abs(error_deg) > t.stall_error_deg
        and abs(velocity) < t.stall_velocity_deg_s
    )


def model(residual_deg: float | None, velocity_deg_s: float, t: Thresholds) -> bool:
    """Method 5: the joint is not where the smoothing model says it should be. The tolerance
    grows with the predicted speed: a sample stamped ``timing_tolerance_s`` late (feedback
    jitter, transport latency) is that much further along the predicted path."""
    tolerance = t.model_error_deg + abs(velocity_deg_s) * t.timing_tolerance_s
    return residual_deg is not None and abs(residual_deg) > tolerance


def reversals(samples: Samples, since_s: float, min_step_deg: float) -> int:
    """Direction reversals after ``since_s`` whose steps on both sides exceed ``min_step_deg``."""
    steps = [
        a1 - a0
        for (t0, a0), (_t1, a1) in zip(list(samples)[:-1], list(samples)[1:])
        if t0 >= since_s
    ]
    big = [s for s in steps if abs(s) > min_step_deg]
    return sum(1 for s0, s1 in zip(big[:-1], big[1:]) if (s0 > 0) != (s1 > 0))


def oscillation(samples: Samples, target_since_s: float, now_s: float, t: Thresholds) -> bool:
    """Method 4: servo hunting, the joint reverses often while its target stays the same."""
    since = max(now_s - t.oscillation_window_s, target_since_s)
    return reversals(samples, since, t.oscillation_step_deg) >= t.oscillation_reversals
