"""Fault injection requests for the simulated arm (``arm/<arm>/sim/fault``, simulator only).

A test or an operator rehearsing failures sends one of these as a Zenoh query; the simulator
applies it on its own thread and replies ``{"ok": true}`` or an error.
"""

from __future__ import annotations

import math

from msgspec import Struct

from fleet.d1.protocol import ERROR_STATUS_NORMAL, ERROR_STATUS_RANGE
from fleet.sim.model import Faults
from fleet.sim.obstacles import Obstacle
from fleet.wire.messages import Text
from fleet.wire.payloads import PayloadKind, payload_kind


class _Fault(Struct, tag_field="op", forbid_unknown_fields=True, frozen=True):
    pass


class Stall(_Fault, tag="stall", frozen=True):
    """An obstacle: ``joint`` cannot move past ``angle_deg``."""

    joint: int
    angle_deg: float


class Unstall(_Fault, tag="unstall", frozen=True):
    """Remove the obstacle on ``joint``."""

    joint: int


class MotorOffline(_Fault, tag="motor_offline", frozen=True):
    """Motor ``joint`` stops (reports status 0 and does not move) while ``offline``."""

    joint: int
    offline: bool = True


class ErrorStatus(_Fault, tag="error_status", frozen=True):
    """The arm reports an abnormal ``error_status`` while ``error``: ``value`` if given (a
    bitfield, as the contact plan expects; it stays the arm's abnormal value until changed,
    `clear` included), else the arm's own (0, or the inventory's ``sim_error_status``)."""

    error: bool = True
    value: int | None = None


class DropFeedback(_Fault, tag="drop_feedback", frozen=True):
    """The arm stops publishing feedback while ``on``."""

    on: bool = True


class MuteAcks(_Fault, tag="mute_acks", frozen=True):
    """The arm executes commands but never acknowledges them while ``on``."""

    on: bool = True


class Drag(_Fault, tag="drag", frozen=True):
    """A hand drags unloaded ``joint`` to ``angle_deg`` at ``speed_deg_s`` (drag-teach, mirror
    tests); a loaded joint resists. The hand keeps it there; a new drag or `clear` replaces it."""

    joint: int
    angle_deg: float
    speed_deg_s: float = 60.0


class AddObstacle(_Fault, tag="obstacle", frozen=True):
    """A compliant obstacle at ``angle_deg`` on ``joint`` (from the side the joint is on).

    ``compliance``: penetration per degree of push (0 rigid); ``hunting_deg``/``hunting_hz``:
    servo hunting while pushing; ``to_deg``/``speed_deg_s``: the obstacle moves (it pushes into
    a held joint: an unexpected contact); ``error_after_s``: the arm flags ``error_status``
    after pushing this long (whether a real D1 does is unknown)."""

    joint: int
    angle_deg: float
    compliance: float = 0.1
    hunting_deg: float = 0.0
    hunting_hz: float = 3.0
    to_deg: float | None = None
    speed_deg_s: float = 0.0
    error_after_s: float | None = None


class RemoveObstacle(_Fault, tag="remove_obstacle", frozen=True):
    """Remove the obstacle (or gripped object) on ``joint``."""

    joint: int


class GripObject(_Fault, tag="grip_object", frozen=True):
    """An object between the fingers: the gripper (joint 6) cannot close below ``width_deg``."""

    width_deg: float
    compliance: float = 0.05


class Noise(_Fault, tag="noise", frozen=True):
    """Gaussian noise of ``noise_deg`` on reported angles, feedback period jitter up to
    ``jitter_s`` (both seeded)."""

    noise_deg: float = 0.05
    jitter_s: float = 0.02


class ClearFaults(_Fault, tag="clear", frozen=True):
    """Remove every injected fault."""


Fault = (
    Stall
    | Unstall
    | MotorOffline
    | ErrorStatus
    | DropFeedback
    | MuteAcks
    | Drag
    | AddObstacle
    | RemoveObstacle
    | GripObject
    | Noise
    | ClearFaults
)

FAULT: PayloadKind[Fault] = payload_kind("sim/fault", Fault, 4096)
"""Fault requests, decoded like every key-space payload (size-capped; PayloadError only)."""


class FaultReply(Struct, frozen=True):
    """The simulator's answer to a fault request."""

    ok: bool
    error: Text | None = None


def apply_fault(faults: Faults, fault: Fault) -> None:
    """Change ``faults`` as ``fault`` asks; raises ValueError for a joint outside 0..6."""
    joint = getattr(fault, "joint", 0)
    if not 0 <= joint <= 6:
        raise ValueError(f"joint {joint} is outside 0..6")
    if isinstance(fault, Stall):
        faults.stalls[fault.joint] = fault.angle_deg
    elif isinstance(fault, Unstall):
        faults.stalls.pop(fault.joint, None)
    elif isinstance(fault, MotorOffline):
        if fault.offline:
            faults.motors_offline.add(fault.joint)
        else:
            faults.motors_offline.discard(fault.joint)
    elif isinstance(fault, ErrorStatus):
        if fault.value is not None:
            faults.abnormal_value = abnormal_error_status(fault.value)
        faults.error_status = fault.error
    elif isinstance(fault, DropFeedback):
        faults.drop_feedback = fault.on
    elif isinstance(fault, MuteAcks):
        faults.mute_acks = fault.on
    elif isinstance(fault, Drag):
        if fault.speed_deg_s <= 0 or not math.isfinite(fault.angle_deg + fault.speed_deg_s):
            raise ValueError("drag needs a finite angle_deg and a speed_deg_s above 0")
        faults.drags[fault.joint] = (fault.angle_deg, fault.speed_deg_s)
    elif isinstance(fault, (AddObstacle, RemoveObstacle, GripObject, Noise)):
        _apply_contact_fault(faults, fault)
    elif isinstance(fault, ClearFaults):
        fresh = Faults()
        faults.stalls, faults.motors_offline = fresh.stalls, fresh.motors_offline
        faults.drags, faults.obstacles = fresh.drags, fresh.obstacles
        faults.noise_deg = faults.jitter_s = 0.0
        faults.error_status = faults.drop_feedback = faults.mute_acks = False


def abnormal_error_status(value: int) -> int:
    """``value`` if a D1 could report it as an abnormal ``error_status``; else ValueError."""
    low, high = ERROR_STATUS_RANGE
    if isinstance(value, bool) or not low <= value <= high or value == ERROR_STATUS_NORMAL:
        raise ValueError(
            f"error_status {value} cannot report an abnormal arm: 1 is normal; use 0 or "
            "another 64-bit integer (a bitfield)"
        )
    return value


def _apply_contact_fault(
    faults: Faults, fault: AddObstacle | RemoveObstacle | GripObject | Noise
) -> None:
    """The contact faults (obstacles, gripped objects, noise); ValueError for bad figures."""
    if isinstance(fault, RemoveObstacle):
        faults.obstacles.pop(fault.joint, None)
        return
    if isinstance(fault, Noise):
        if not (0.0 <= fault.noise_deg <= 5.0 and 0.0 <= fault.jitter_s <= 0.5):
            raise ValueError("noise needs 0 <= noise_deg <= 5 and 0 <= jitter_s <= 0.5")
        faults.noise_deg, faults.jitter_s = fault.noise_deg, fault.jitter_s
        return
    if not 0.0 <= fault.compliance < 1.0:
        raise ValueError("compliance must be in 0..1 (0 = rigid)")
    if isinstance(fault, GripObject):
        faults.obstacles[6] = Obstacle(fault.width_deg, fault.compliance, side=-1)
        return
    values = (fault.angle_deg, fault.hunting_deg, fault.hunting_hz, fault.speed_deg_s)
    if not all(math.isfinite(v) for v in values) or fault.hunting_deg < 0:
        raise ValueError("obstacle figures must be finite and hunting_deg >= 0")
    faults.obstacles[fault.joint] = Obstacle(
        angle_deg=fault.angle_deg,
        compliance=fault.compliance,
        hunting_deg=fault.hunting_deg,
        hunting_hz=fault.hunting_hz,
        to_deg=fault.to_deg,
        speed_deg_s=fault.speed_deg_s,
        error_after_s=fault.error_after_s,
    )
