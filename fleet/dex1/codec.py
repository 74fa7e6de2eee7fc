"""The Dex1-1 codec: decoded DDS samples <-> typed readings and targets; limits. Pure.

Position mapping (seed 003, as Unitree's Dex1-1 service and its EZGripper drop-in read it):
``q`` in radians, 0 = closed, 2*pi = fully open; opening percent = q / (2*pi) * 100, with
readings at or below 0.1 rad reported as 0 % and at or above 6.0 rad as 100 %.
A sample is hostile until checked: its motor list must hold 1..MAX_MOTORS entries and every
number we use must be finite; anything else is a ``BadSample`` (counted by the agent).
"""

from __future__ import annotations

import math
import struct
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
"""family -> Reading of a sample decoded by the binding (the slow path, see ``CDR_READERS``)."""

# ----------------------------------------------------------------------------- serialized
# The relay's hot path reads the few fields it needs straight from the serialized sample: the
# binding's generic IDL deserialiser builds every field of every nested struct (a HandState_ is
# 40 numbers and 4 objects) and cost most of a 500 Hz gripper's CPU. Layouts follow the IDL in
# ``idl.py`` (every struct final; no 8-byte members, so XCDR1 and plain XCDR2 align alike);
# offsets are from the start of the body (after the 4-byte encapsulation header).

_ENCODINGS = {0x0000: (">", 0), 0x0001: ("<", 0), 0x0006: (">", 4), 0x0007: ("<", 4)}
"""CDR and plain XCDR2, big and little endian -> (byte order, bytes of the DHEADER that XCDR2
puts before a sequence of structs). Anything else: ``UnsupportedEncoding``."""
_GO_STATE = 48
"""bytes of one ``unitree_go`` MotorState_: mode, 7 float32, temperature, lost, reserve[2]."""
_HG_STATE = 56
"""bytes of one ``unitree_hg`` MotorState_: mode, 4 float32, int16[2], vol, sensor[2],
motorstate, reserve[4]."""
_PRESS = 104
"""bytes of one PressSensorState_: float32[12] twice, lost, reserve."""
_HG_TAIL = 56 + 16
"""IMUState_ (13 float32 and an int16, padded to 4) and power_v, power_a, system_v, device_v:
from the end of ``press_sensor_state`` to ``error``."""
_MOTOR_BYTES = {"go": _GO_STATE, "hg": _HG_STATE}
_COUNT_AND_Q = {
    kind: struct.Struct(f"{order}{dh}xI4xf") for kind, (order, dh) in _ENCODINGS.items()
}
"""The motor count and the first motor's q in one unpack from offset 4 (both families)."""


class UnsupportedEncoding(ValueError):
    """A serialized sample in an encapsulation this reader does not lay out (decode it with the
    binding instead)."""


def _encoding(serialized: bytes) -> tuple[str, int]:
    if len(serialized) < 8:
        raise BadSample(f"{len(serialized)} bytes: no state sample")
    kind = int.from_bytes(serialized[:2], "big")
    found = _ENCODINGS.get(kind)
    if found is None:
        raise UnsupportedEncoding(f"encapsulation 0x{kind:04x}")
    return found


def _count(serialized: bytes, order: str, offset: int, what: str) -> int:
    if offset + 4 > len(serialized):
        raise BadSample(f"{what}: sample ends at {len(serialized)} bytes")
    (count,) = struct.unpack_from(order + "I", serialized, offset)
    return int(count)


def _motors(serialized: bytes, order: str, dh: int, family: str) -> int:
    """The first motor's offset, after checking the motor list's count and length."""
    count = _count(serialized, order, 4 + dh, "motor list")
    if not 1 <= count <= MAX_MOTORS:
        raise BadSample(f"the state holds {count} motors (a Dex1-1 sends 1..{MAX_MOTORS})")
    if len(serialized) < 8 + dh + count * _MOTOR_BYTES[family]:
        raise BadSample(f"{count} motors in {len(serialized)} bytes")
    return 8 + dh


def position_cdr(serialized: bytes, family: str) -> float:
    """Only the first motor's position of a serialized state sample of ``family`` (the relay
    runs grip detection on every sample but decodes in full only the newest of a batch);
    BadSample when it is not one, or the position is not finite and plausible."""
    layout = _COUNT_AND_Q.get(int.from_bytes(serialized[:2], "big"))
    if layout is None or len(serialized) < layout.size + 4:
        _encoding(serialized)  # raises the precise error (too short, or UnsupportedEncoding)
        raise BadSample(f"{len(serialized)} bytes: no state sample")
    count, q = layout.unpack_from(serialized, 4)
    dh = layout.size - 12
    if not 1 <= count <= MAX_MOTORS or len(serialized) < 8 + dh + count * _MOTOR_BYTES[family]:
        raise BadSample(f"{count} motors in {len(serialized)} bytes")
    if not Q_PLAUSIBLE_RAD[0] <= q <= Q_PLAUSIBLE_RAD[1]:  # False for NaN too
        raise BadSample(f"position {q!r} rad is outside {Q_PLAUSIBLE_RAD}")
    return float(q)


def reading_from_go_cdr(serialized: bytes) -> Reading:
    """A serialized ``MotorStates_`` -> its first motor's Reading (BadSample otherwise)."""
    order, dh = _encoding(serialized)
    at = _motors(serialized, order, dh, "go")
    q, dq, _ddq, tau = struct.unpack_from(order + "4f", serialized, at + 4)
    (lost,) = struct.unpack_from(order + "I", serialized, at + 36)
    return _checked(Reading(q, dq, tau, float(serialized[at + 32]), 0, int(lost)))


def reading_from_hg_cdr(serialized: bytes) -> Reading:
    """A serialized ``HandState_`` -> its first motor's Reading (BadSample otherwise)."""
    order, dh = _encoding(serialized)
    at = _motors(serialized, order, dh, "hg")
    count = _count(serialized, order, 4 + dh, "motor list")
    press_at = at + count * _HG_STATE + dh
    presses = _count(serialized, order, press_at, "HandState_.press_sensor_state")
    error_at = press_at + 4 + presses * _PRESS + _HG_TAIL
    if presses > len(serialized) or error_at + 16 > len(serialized):
        raise BadSample(f"HandState_ with {presses} press sensors in {len(serialized)} bytes")
    q, dq, _ddq, tau, t0, t1 = struct.unpack_from(order + "4f2h", serialized, at + 4)
    (bits,) = struct.unpack_from(order + "I", serialized, at + 36)
    (error,) = struct.unpack_from(order + "I", serialized, error_at)
    return _checked(Reading(q, dq, tau, float(max(t0, t1)), int(bits) | int(error), 0))


CDR_READERS = {"hg": reading_from_hg_cdr, "go": reading_from_go_cdr}
"""family -> Reading of a serialized state sample (the relay's hot path)."""


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
