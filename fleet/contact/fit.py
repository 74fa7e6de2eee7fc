"""Calibration: the step routine's plan and the fit of a joint's response to it. Pure.

The routine (``fleet calibrate``; the benchmark runs the same plan on simulated arms): per
joint and smoothing mode (1, then 0), steps of ``STEP_SIZES_DEG`` away from the joint's current
angle towards the middle of its range and back, each waited out until the joint is still. The
fit simulates ``dynamics.JointResponse`` over the recorded steps and searches the figures (speed
limit, lag, dead time, then a second-order servo if that fits better) that minimise the RMS
error; it starts from estimates read off the steps (the fastest speed, the first motion).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

from fleet.contact.calibration import JointCalibration
from fleet.contact.dynamics import ArmDynamics, JointResponse, ModeDynamics

STEP_SIZES_DEG = (10.0, 40.0, 80.0)
"""Small enough to be slow and local; 80 deg shows the speed limit of any arm whose lag times
its speed limit is below 80 deg (a 0.5 s lag at 160 deg/s), for several feedback samples even
at 180 deg/s (a 40 deg step at that speed is over in two)."""
MODES = (1, 0)
SETTLE_TOLERANCE_DEG = 0.5
STALL_SHORT_DEG = 2.0
"""A step that ends still more than this short of its target met an obstacle: stop."""


@dataclass
class StepRecord:
    """One step: sent at ``sent_s`` from ``start_deg`` to ``target_deg`` in ``mode``; the
    angles reported after it (time s, deg), in the same clock."""

    mode: int
    sent_s: float
    start_deg: float
    target_deg: float
    samples: list[tuple[float, float]] = field(default_factory=list)


def plan(angle_deg: float, limits: tuple[float, float]) -> list[tuple[int, float]]:
    """The (mode, target) steps for a joint at ``angle_deg``: out towards the middle of its
    range and back, each size and mode (keeping 2 deg from either limit)."""
    lo, hi = limits[0] + 2.0, limits[1] - 2.0
    base = min(max(angle_deg, lo), hi)
    direction = 1.0 if base <= (lo + hi) / 2 else -1.0
    room = (hi - base) if direction > 0 else (base - lo)
    steps: list[tuple[int, float]] = []
    for mode in MODES:
        for size in STEP_SIZES_DEG:
            out = base + direction * min(size, room)
            steps += [(mode, round(out, 2)), (mode, round(base, 2))]
    return steps


def simulate(d: ModeDynamics, record: StepRecord) -> list[float]:
    """The angles ``d`` predicts at the record's sample times."""
    both = ArmDynamics(mode0=d, mode1=d)
    response = JointResponse(record.start_deg)
    response.mode = record.mode
    response.command(record.target_deg, record.mode, record.sent_s, d.dead_s)
    now, out = record.sent_s, []
    for stamp, _angle in record.samples:
        if stamp > now:
            response.advance(both, now, stamp)
            now = stamp
        out.append(response.angle_deg)
    return out


def rms(d: ModeDynamics, records: list[StepRecord]) -> float:
    """RMS error (deg) of ``d`` over every sample of ``records``."""
    total, count = 0.0, 0
    for record in records:
        for predicted, (_t, angle) in zip(simulate(d, record), record.samples, strict=True):
            total += (predicted - angle) ** 2
            count += 1
    return math.sqrt(total / count) if count else math.inf


def timing_rms(d: ModeDynamics, records: list[StepRecord], timing_s: float) -> float:
    """RMS (deg) of the part of ``d``'s residual that late report stamps do not explain: each
    sample's |residual| less the model's speed around it times ``timing_s`` (the detector's own
    timing allowance), at least 0. A fit's plain RMS counts the jitter of the routine's reports
    at speed as model error, and the detector already allows for that jitter."""
    total, count = 0.0, 0
    for record in records:
        predicted = simulate(d, record)
        stamps = [record.sent_s] + [t for t, _a in record.samples]
        angles = [record.start_deg, *predicted]
        speeds = [
            abs(angles[k + 1] - angles[k]) / max(stamps[k + 1] - stamps[k], 1e-3)
            for k in range(len(predicted))
        ]
        for k, (_t, angle) in enumerate(record.samples):
            around = max(speeds[k], speeds[k + 1] if k + 1 < len(speeds) else 0.0)
            excess = max(0.0, abs(predicted[k] - angle) - around * timing_s)
            total += excess**2
            count += 1
    return round(math.sqrt(total / count), 3) if count else math.inf


def _initial(records: list[StepRecord]) -> ModeDynamics:
    speed, dead = 1.0, []
    for record in records:
        previous = (record.sent_s, record.start_deg)
        for stamp, angle in record.samples:
            if stamp - previous[0] > 0.02:
                speed = max(speed, abs(angle - previous[1]) / (stamp - previous[0]))
            previous = (stamp, angle)
        moved = [t for t, a in record.samples if abs(a - record.start_deg) > 0.3]
        if moved:
            dead.append(max(0.0, moved[0] - record.sent_s - 0.1))
    return ModeDynamics(
        rate_deg_s=min(max(speed, 2.0), 900.0),
        lag_s=0.05,
        dead_s=min(dead) if dead else 0.0,
    )


_BOUNDS = {
    "rate_deg_s": (1.0, 1000.0),
    "lag_s": (0.0, 5.0),
    "dead_s": (0.0, 1.0),
    "servo_hz": (0.3, 20.0),
    "overshoot": (0.0, 0.3),
}
_STEP = {"rate_deg_s": 0.3, "lag_s": 0.05, "dead_s": 0.03, "servo_hz": 0.5, "overshoot": 0.05}
_RELATIVE = {"rate_deg_s", "servo_hz"}


def _search(
    d: ModeDynamics, names: tuple[str, ...], rms_of: Callable[[ModeDynamics], float]
) -> ModeDynamics:
    """Coordinate search: each figure up or down by its step, steps halve when nothing helps."""
    best, cost = d, rms_of(d)
    steps = {n: _STEP[n] for n in names}
    for _round in range(60):
        improved = False
        for name in names:
            value = getattr(best, name)
            lo, hi = _BOUNDS[name]
            step = steps[name]
            if name in _RELATIVE:
                candidates = (value * (1 + step), value / (1 + step))
            else:
                candidates = (value + step, value - step)
            for candidate in candidates:
                trial = _with(best, name, min(max(candidate, lo), hi))
                trial_cost = rms_of(trial)
                if trial_cost < cost - 1e-6:
                    best, cost, improved = trial, trial_cost, True
                    break
        if not improved:
            steps = {n: s / 2 for n, s in steps.items()}
            if all(s < 0.002 for s in steps.values()):
                break
    return best


def _with(d: ModeDynamics, name: str, value: float) -> ModeDynamics:
    figures = {f: getattr(d, f) for f in ModeDynamics.__struct_fields__}
    figures[name] = round(value, 4)
    return ModeDynamics(**figures)


def feedback_jitter_s(records: list[StepRecord]) -> float:
    """Twice the 95th percentile of how far report intervals deviate from their median
    (seconds): a bound on how late a report can be stamped."""
    intervals = [
        b[0] - a[0] for r in records for a, b in zip(r.samples[:-1], r.samples[1:], strict=True)
    ]
    if len(intervals) < 10:
        return 0.0
    median = sorted(intervals)[len(intervals) // 2]
    deviations = sorted(abs(i - median) for i in intervals)
    return round(2.0 * deviations[int(0.95 * (len(deviations) - 1))], 4)


def fit(records: list[StepRecord]) -> tuple[ModeDynamics, float]:
    """The dynamics of one mode that best explain ``records``, and its RMS error (deg). Several
    starts (dead times; servo frequencies) keep the search out of local minima."""
    initial = _initial(records)
    # The searches revisit points (a step back, a clamp at a bound, the starts' minima): each
    # figure set is simulated once.
    rms_of = functools.cache(lambda d: rms(d, records))
    first_names = ("rate_deg_s", "lag_s", "dead_s")
    starts = [initial, _with(initial, "dead_s", 0.05), _with(initial, "dead_s", 0.1)]
    firsts = [_search(start, first_names, rms_of) for start in starts]
    best = min(firsts, key=rms_of)
    cost = rms_of(best)
    second_names = ("servo_hz", "overshoot", "rate_deg_s", "lag_s", "dead_s")
    seconds = [
        _search(_with(_with(best, "servo_hz", hz), "overshoot", 0.05), second_names, rms_of)
        for hz in (1.0, 2.5, 6.0)
    ]
    second = min(seconds, key=rms_of)
    second_cost = rms_of(second)
    if second_cost < min(0.7 * cost, cost - 0.05):  # a servo only when it explains clearly more
        best, cost = second, second_cost
    return best, round(cost, 3)


def fit_joint(joint: int, records: list[StepRecord], timing_s: float) -> JointCalibration:
    """Fit both modes of ``joint`` from its routine's ``records`` (``fleet calibrate`` and the
    benchmark); ``timing_s``: the detector's timing allowance on this arm (the larger of its
    ``timing_tolerance_s`` and the routine's feedback jitter)."""
    by_mode = {mode: [r for r in records if r.mode == mode] for mode in (0, 1)}
    (mode0, rms0), (mode1, rms1) = fit(by_mode[0]), fit(by_mode[1])
    excess = max(timing_rms(mode0, by_mode[0], timing_s), timing_rms(mode1, by_mode[1], timing_s))
    return JointCalibration(joint, mode0, mode1, max(rms0, rms1), timing_rms_deg=excess)
