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


def stall(samples: Samples, errors: Samples, demand: int, t: Thresholds) -> bool:
    """Method 2 (with 1): the joint does not follow its target, whatever its dynamics.

    Fires when, over the last ``stall_window_s`` (from the newest sample at least that old),
    the tracking error stayed above ``stall_error_deg`` on one side (the side the joint was sent
    to: a joint past its target is overshooting, not blocked) while the joint progressed towards
    its target slower than ``min(stall_velocity_deg_s, error / stall_lag_s)``. Any plausible free
    D1 (speed limits from 20 deg/s, first-order lags up to 0.5 s, second-order servos,
    dead time up to 0.1 s) moves at least twice that fast once the window has passed its dead
    time; a blocked joint does not move, a pushed one moves away. ``errors`` holds (time,
    target - measured) aligned with ``samples``; ``demand`` is the side the joint was sent
    to (+1, -1, or 0 for a joint holding where it was)."""
    if len(samples) < 2 or len(errors) != len(samples):
        return False
    now_s, angle = samples[-1]
    error = errors[-1][1]
    if abs(error) <= t.stall_error_deg or demand * error < 0:
        return False
    sign = 1.0 if error > 0 else -1.0
    smallest = abs(error)
    start: tuple[float, float] | None = None
    for (stamp, then), (_s, then_error) in zip(reversed(samples), reversed(errors)):
        if sign * then_error <= t.stall_error_deg:
            return False
        smallest = min(smallest, abs(then_error))
        if now_s - stamp >= t.stall_window_s:
            start = (stamp, then)
            break
    if start is None:
        return False
    progress_deg_s = sign * (angle - start[1]) / (now_s - start[0])
    return progress_deg_s < min(t.stall_velocity_deg_s, smallest / t.stall_lag_s)


def model_tolerance(
    velocity_deg_s: float, t: Thresholds, timing_s: float = 0.0, travel_deg: float = 0.0
) -> float:
    """Method 5's tolerance at a predicted speed (see ``model``); ``timing_s``: the arm's own
    feedback jitter when it is larger than ``timing_tolerance_s``; ``travel_deg``: how far the
    model moved over that timing window (a report stamped late by it lags the model by up to
    this, even when the model has just stopped: the end of a fast rate-limited step)."""
    timing = max(t.timing_tolerance_s, timing_s)
    return t.model_error_deg + max(abs(velocity_deg_s) * timing, travel_deg)


def behind(residual_deg: float | None, demand: int) -> float | None:
    """How far the joint is *behind* the model (measured minus predicted, towards where it was
    sent): a contact resists motion, it never puts a joint ahead of its model. ``demand`` 0
    (a joint holding its place): either way."""
    if residual_deg is None:
        return None
    return abs(residual_deg) if demand == 0 else -residual_deg * demand


def model(
    lag_deg: float | None,
    velocity_deg_s: float,
    t: Thresholds,
    slack_deg: float,
    timing_s: float,
    travel_deg: float = 0.0,
) -> bool:
    """Method 5: the joint lags where the model of this arm says it should be (``behind``). The
    tolerance grows with the predicted speed: a sample stamped ``timing_tolerance_s`` late
    (feedback jitter, transport latency) is that much further along the predicted path; and
    with the calibration's own error (``slack_deg``)."""
    tolerance = model_tolerance(velocity_deg_s, t, timing_s, travel_deg) + slack_deg
    return lag_deg is not None and lag_deg > tolerance


def reversals(samples: Samples, since_s: float, min_step_deg: float) -> int:
    """Direction reversals after ``since_s`` whose steps on both sides exceed ``min_step_deg``."""
    steps = [
        a1 - a0
        for (t0, a0), (_t1, a1) in zip(list(samples)[:-1], list(samples)[1:])
        if t0 >= since_s
    ]
    big = [s for s in steps if abs(s) > min_step_deg]
    return sum(1 for s0, s1 in zip(big[:-1], big[1:]) if (s0 > 0) != (s1 > 0))


def oscillation(
    samples: Samples, errors: Samples, target_since_s: float, now_s: float, t: Thresholds
) -> bool:
    """Method 4: servo hunting, the joint reverses often while its target stays the same and
    it stays short of it (more than ``stall_error_deg``, one side): a second-order servo ringing
    about its target (plausible D1s overshoot up to 10 %) crosses it and is no
    contact."""
    since = max(now_s - t.oscillation_window_s, target_since_s)
    window = [e for s, e in errors if s > since]
    if not window or not (
        all(e > t.stall_error_deg for e in window) or all(e < -t.stall_error_deg for e in window)
    ):
        return False
    return reversals(samples, since, t.oscillation_step_deg) >= t.oscillation_reversals
