"""The G1 LocoClient over DDS, as unitree_sdk2 defines it, and the FSM table of seed 004. Pure.

Topics ``rt/api/loco/request`` / ``rt/api/loco/response`` (``rt/api/<service>/...``, service
``loco``). API ids from unitree_sdk2's ``g1_loco_api``: 7001 GetFsmId, 7002 GetFsmMode, 7101
SetFsmId, 7102 SetBalanceMode, 7105 SetVelocity. The client's calls map onto them as Unitree's
SDK does: Damp = SetFsmId(1), Start = SetFsmId(500), StandUp = SetFsmId(4) (lock standing),
BalanceStand = SetBalanceMode(0), StopMove = SetVelocity(0, 0, 0, 1 s). Parameters are JSON
(``{"data": x}``; SetVelocity ``{"velocity": [vx, vy, omega], "duration": d}``); GetFsmId
answers ``{"data": id}``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

SERVICE = "loco"
REQUEST_TOPIC = f"rt/api/{SERVICE}/request"
RESPONSE_TOPIC = f"rt/api/{SERVICE}/response"
STATE_TOPIC = "rt/sportmodestate"

GET_FSM_ID = 7001
GET_FSM_MODE = 7002
SET_FSM_ID = 7101
SET_BALANCE_MODE = 7102
SET_VELOCITY = 7105
API_IDS = frozenset({GET_FSM_ID, GET_FSM_MODE, SET_FSM_ID, SET_BALANCE_MODE, SET_VELOCITY})

FSM_NAMES: dict[int, str] = {
    0: "zero torque",
    1: "damping",
    2: "position control squat",
    3: "position control sit down",
    4: "lock standing",
    500: "walk",
    501: "walk (3-dof waist)",
    702: "lie down / stand up",
    706: "balance squat / squat stand",
    801: "run",
    802: "run",
}
"""Seed 004's table of FSM ids (801 is 802 on 29-dof ai_sport after 8.6.x.x)."""
DAMP_FSM = 1
WALK_FSMS = frozenset({500, 501, 801, 802})
STATIC, DYNAMIC = 0, 1


def fsm_name(fsm_id: int) -> str:
    """The seed's name of ``fsm_id`` (``unknown <id>`` for ids it does not list)."""
    return FSM_NAMES.get(fsm_id, f"unknown {fsm_id}")


@dataclass(frozen=True)
class Call:
    """One RPC: the API id and its JSON parameter."""

    api_id: int
    parameter: str
    switches_mode: bool
    """A mode switch: refused in a dynamic state unless it is damping (seed 004)."""


def call_for(
    op: str, vx: float = 0.0, vy: float = 0.0, omega: float = 0.0, duration_s: float = 1.0
) -> Call:
    """The RPC of one fleet op (``damp``, ``start``, ``stand_up``, ``balance_stand``,
    ``stop_move``, ``set_velocity``, ``get_fsm_id``); ValueError for another."""
    data = {
        "damp": (SET_FSM_ID, {"data": DAMP_FSM}, False),
        "start": (SET_FSM_ID, {"data": 500}, True),
        "stand_up": (SET_FSM_ID, {"data": 4}, True),
        "balance_stand": (SET_BALANCE_MODE, {"data": 0}, True),
        "stop_move": (SET_VELOCITY, {"velocity": [0.0, 0.0, 0.0], "duration": 1.0}, False),
        "set_velocity": (
            SET_VELOCITY,
            {"velocity": [vx, vy, omega], "duration": duration_s},
            False,
        ),
        "get_fsm_id": (GET_FSM_ID, {}, False),
    }.get(op)
    if data is None:
        raise ValueError(f"no LocoClient call for {op!r}")
    api_id, parameter, switches = data
    return Call(api_id, json.dumps(parameter), switches)


def refusal(op: str, call: Call, fsm_id: int, fsm_mode: int) -> str | None:
    """Why seed 004 refuses ``op`` in this state, or None: in a dynamic state (fsm_mode 1)
    switching to any mode but damping is not allowed (damping, the fallback, always is)."""
    if call.switches_mode and fsm_mode == DYNAMIC:
        return (
            f"{op} switches the G1's mode, and it is in a dynamic state (fsm_mode 1, fsm "
            f"{fsm_id} {fsm_name(fsm_id)}): seed 004 allows only damping then; send stop_move "
            "and retry once fsm_mode is 0 (static)"
        )
    return None


def velocity_problem(
    vx: float, vy: float, omega: float, duration_s: float, limits: tuple[float, float, float, float]
) -> str | None:
    """Why a velocity command is out of bounds (3204), or None. ``limits``: max |vx|, |vy|,
    |omega| and the longest duration (a bounded duration: never Move's 864000 s)."""
    values = (vx, vy, omega, duration_s)
    if not all(math.isfinite(v) for v in values):
        return "every value must be a finite number"
    for name, value, limit in zip(("vx", "vy", "omega"), values, limits, strict=False):
        if abs(value) > limit:
            return f"{name} {value:g} is outside -{limit:g}..{limit:g}"
    if not 0 < duration_s <= limits[3]:
        return f"duration_s {duration_s:g} is outside 0..{limits[3]:g} (a bounded duration)"
    return None


def parse_data(data: str) -> int | None:
    """The integer ``data`` of a GetFsmId / GetFsmMode answer, or None if it has none."""
    try:
        value = json.loads(data).get("data") if data else None
    except (ValueError, AttributeError):
        return None
    return value if isinstance(value, int) and not isinstance(value, bool) else None
