"""The G1's key-space payloads (``fleet/<fleet>/g1/<id>/...``), msgspec Structs."""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta, Struct

from fleet.wire.messages import Count, DeviceCommand, StampNs, Text
from fleet.wire.messages import DeviceRelease as Release

Speed = Annotated[float, Meta(ge=-10.0, le=10.0)]


class G1State(Struct, frozen=True):
    """``g1/<id>/state``: the newest ``rt/sportmodestate`` with the FSM named (seed 004),
    put on every change of fsm_id / fsm_mode and at ``relay_hz``."""

    stamp_ns: StampNs
    fsm_id: int
    fsm_name: str
    fsm_mode: int
    mode: Literal["static", "dynamic", "unknown"]
    task_id: int
    task_time: float
    link: Literal["ok", "stale"]
    estopped: bool
    stop_reason: Text | None
    stop_action: str
    dds_samples: Count
    bad_samples: Count
    dds_rate_hz: float
    service: str | None = None
    """The LocoClient service name commands go to (``sport``/``loco``; None: ``auto`` still
    asking both)."""
    service_setting: str = "sport"
    """The inventory's ``service`` (``sport``, ``loco`` or ``auto``)."""
    service_answered: bool = False
    """The service answered GetFsmId (someone serves ``rt/api/<service>``)."""
    stop_detail: Text | None = None
    """The latched stop's state when not confirmed (``unconfirmed: no state``)."""


class _G1Command(DeviceCommand, kw_only=True):
    pass


class Damp(_G1Command, tag="damp", kw_only=True):
    """SetFsmId(1): damping (always allowed; the robot sinks)."""


class Start(_G1Command, tag="start", kw_only=True):
    """SetFsmId(500): the walking controller."""


class StandUp(_G1Command, tag="stand_up", kw_only=True):
    """SetFsmId(4): lock standing."""


class BalanceStand(_G1Command, tag="balance_stand", kw_only=True):
    """SetBalanceMode(0)."""


class ContinuousGait(_G1Command, tag="continuous_gait", kw_only=True):
    """SetBalanceMode(1 if on else 0): with ``on`` the robot keeps stepping at zero velocity
    (a fleet stop turns it off)."""

    on: bool


class StopMove(_G1Command, tag="stop_move", kw_only=True):
    """SetVelocity(0, 0, 0)."""


class SetVelocity(_G1Command, tag="set_velocity", kw_only=True):
    """SetVelocity(vx, vy, omega, duration_s): m/s, m/s, rad/s, a bounded duration."""

    vx: Speed = 0.0
    vy: Speed = 0.0
    omega: Speed = 0.0
    duration_s: Annotated[float, Meta(gt=0.0, le=60.0)] = 1.0


class GetFsmId(_G1Command, tag="get_fsm_id", kw_only=True):
    """GetFsmId: the reply's ``result`` is the id."""


G1Command = (
    Damp
    | Start
    | StandUp
    | BalanceStand
    | ContinuousGait
    | StopMove
    | SetVelocity
    | GetFsmId
    | Release
)
OPS = {
    Damp: "damp",
    Start: "start",
    StandUp: "stand_up",
    BalanceStand: "balance_stand",
    ContinuousGait: "continuous_gait",
    StopMove: "stop_move",
    SetVelocity: "set_velocity",
    GetFsmId: "get_fsm_id",
    Release: "release",
}
