"""Fault injection requests for the simulated arm (``arm/<arm>/sim/fault``, simulator only).

A test or an operator rehearsing failures sends one of these as a Zenoh query; the simulator
applies it on its own thread and replies ``{"ok": true}`` or an error.
"""

from __future__ import annotations

import math

import msgspec
from msgspec import Struct

from fleet.sim.model import Faults


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
    """The arm reports ``error_status`` 0 while ``error``."""

    error: bool = True


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


class ClearFaults(_Fault, tag="clear", frozen=True):
    """Remove every injected fault."""


Fault = Stall | Unstall | MotorOffline | ErrorStatus | DropFeedback | MuteAcks | Drag | ClearFaults

fault_decoder: msgspec.json.Decoder[Fault] = msgspec.json.Decoder(Fault)


class FaultReply(Struct, frozen=True):
    """The simulator's answer to a fault request."""

    ok: bool
    error: str | None = None


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
        faults.error_status = fault.error
    elif isinstance(fault, DropFeedback):
        faults.drop_feedback = fault.on
    elif isinstance(fault, MuteAcks):
        faults.mute_acks = fault.on
    elif isinstance(fault, Drag):
        if fault.speed_deg_s <= 0 or not math.isfinite(fault.angle_deg + fault.speed_deg_s):
            raise ValueError("drag needs a finite angle_deg and a speed_deg_s above 0")
        faults.drags[fault.joint] = (fault.angle_deg, fault.speed_deg_s)
    elif isinstance(fault, ClearFaults):
        fresh = Faults()
        faults.stalls, faults.motors_offline = fresh.stalls, fresh.motors_offline
        faults.drags = fresh.drags
        faults.error_status = faults.drop_feedback = faults.mute_acks = False
