"""The Dex1-1 codec: decoded DDS samples <-> typed readings and targets; limits. Pure.

Position mapping (seed 003, as Unitree's Dex1-1 service and its EZGripper drop-in read it):
``q`` in radians, 0 = closed, 2*pi = fully open; opening percent = q / (2*pi) * 100, with
readings at or below 0.1 rad reported as 0 % and at or above 6.0 rad as 100 %.
A sample is hostile until checked: its motor list must hold 1..MAX_MOTORS entries and every
number we use must be finite; anything else is a ``BadSample`` (counted by the agent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

Q_OPEN_RAD = 2.0 * math.pi
"""Fully open."""
Q_CLOSED_SNAP_RAD = 0.1
Q_OPEN_SNAP_RAD = 6.0
MAX_MOTORS = 4
"""A Dex1-1 sends one motor; a sample with more than this many is not a gripper's."""
Q_PLAUSIBLE_RAD = (-1.0, Q_OPEN_RAD + 1.0)
"""A position outside this is a sensor fault or a forgery, never a pose to hold."""


class BadSample(ValueError):
    """A state sample that is not a usable Dex1-1 reading (the message says why)."""


@dataclass(frozen=True)
class Reading:
    """One state sample of one gripper motor, in the wire's units."""

    q_rad: float
    dq_rad_s: float
    tau_est: float
    temperature_c: float
    error: int
    """``hg``: ``motorstate`` bits, or'ed with ``HandState_.error[0]``; ``go``: 0."""
    lost: int
    """``go``: the motor's ``lost`` counter; ``hg``: 0."""

    @property
    def opening_pct(self) -> float:
        """The opening in percent (seed 003's mapping)."""
        return pct_from_rad(self.q_rad)


def pct_from_rad(q_rad: float) -> float:
    """Opening percent of a position (0.1 rad or less: 0 %, 6.0 rad or more: 100 %)."""
    if q_rad <= Q_CLOSED_SNAP_RAD:
        return 0.0
    if q_rad >= Q_OPEN_SNAP_RAD:
        return 100.0
    return q_rad / Q_OPEN_RAD * 100.0


def rad_from_pct(pct: float) -> float:
    """The position of an opening percent (0 % closed, 100 % = 2*pi)."""
    return pct / 100.0 * Q_OPEN_RAD


def _finite(*values: float) -> bool:
    return all(isinstance(v, float | int) and math.isfinite(v) for v in values)


def _motor(motors: Any, what: str) -> Any:
    count = len(motors)
    if not 1 <= count <= MAX_MOTORS:
        raise BadSample(f"{what} holds {count} motors (a Dex1-1 sends 1..{MAX_MOTORS})")
    return motors[0]


def _checked(reading: Reading) -> Reading:
    if not _finite(reading.q_rad, reading.dq_rad_s, reading.tau_est, reading.temperature_c):
        raise BadSample(f"non-finite value in {reading}")
    low, high = Q_PLAUSIBLE_RAD
    if not low <= reading.q_rad <= high:
        raise BadSample(f"position {reading.q_rad:.3f} rad is outside {low:g}..{high:.2f}")
    return reading


def reading_from_hg(sample: Any) -> Reading:
    """A ``HandState_`` -> its first motor's Reading; BadSample otherwise."""
    motor = _motor(sample.motor_state, "HandState_.motor_state")
    temperatures = list(motor.temperature)
    return _checked(
        Reading(
            q_rad=float(motor.q),
            dq_rad_s=float(motor.dq),
            tau_est=float(motor.tau_est),
            temperature_c=float(max(temperatures) if temperatures else 0),
            error=int(motor.motorstate) | int(sample.error[0]),
            lost=0,
        )
    )


def reading_from_go(sample: Any) -> Reading:
    """A ``MotorStates_`` -> its first motor's Reading; BadSample otherwise."""
    motor = _motor(sample.states, "MotorStates_.states")
    return _checked(
        Reading(
            q_rad=float(motor.q),
            dq_rad_s=float(motor.dq),
            tau_est=float(motor.tau_est),
            temperature_c=float(motor.temperature),
            error=0,
            lost=int(motor.lost),
        )
    )


READERS = {"hg": reading_from_hg, "go": reading_from_go}


@dataclass(frozen=True)
class Target:
    """What one command asks of the gripper motor (position mode)."""

    q_rad: float
    tau: float
    kp: float
    kd: float


@dataclass(frozen=True)
class Limits:
    """A gripper's accepted command range (from its inventory entry)."""

    q_min_rad: float
    q_max_rad: float
    tau_max: float
    kp_max: float
    kd_max: float


def target_problem(target: Target, limits: Limits) -> str | None:
    """Why ``target`` may not be sent (3204), or None. Non-finite values are refused first:
    every comparison with NaN is False."""
    if not _finite(target.q_rad, target.tau, target.kp, target.kd):
        return "every value must be a finite number"
    checks = (
        ("q_rad", target.q_rad, limits.q_min_rad, limits.q_max_rad),
        ("tau", target.tau, 0.0, limits.tau_max),
        ("kp", target.kp, 0.0, limits.kp_max),
        ("kd", target.kd, 0.0, limits.kd_max),
    )
    for name, value, low, high in checks:
        if not low <= value <= high:
            return f"{name} {value:g} is outside {low:g}..{high:g}"
    return None
