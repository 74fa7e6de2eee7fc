"""The G1 LocoClient over DDS, as unitree_sdk2 defines it, and the FSM table of seed 004. Pure.

Topics ``rt/api/<service>/request`` / ``rt/api/<service>/response``. The service is named
``sport`` by Unitree's SDK for ai_sport >= 8.2 (``g1_loco_api``'s ``LOCO_SERVICE_NAME``, the
firmware seed 004 describes) and ``loco`` before 8.2: a per-device setting (``G1Config.service``).
API ids from unitree_sdk2's ``g1_loco_api``: 7001 GetFsmId, 7002 GetFsmMode, 7003
GetBalanceMode, 7101 SetFsmId, 7102 SetBalanceMode, 7104 SetStandHeight, 7105 SetVelocity,
7106 SetTaskId (WaveHand, ShakeHand), 7107 SetSpeedMode. The client's calls map onto them as
Unitree's SDK does (unitree_sdk2 ``g1_loco_client.hpp``): Damp = SetFsmId(1), Start =
SetFsmId(500), StandUp = SetFsmId(4) (lock standing), BalanceStand = SetBalanceMode(0),
ContinuousGait(flag) = SetBalanceMode(flag ? 1 : 0), StopMove = SetVelocity(0, 0, 0, 1 s).
Parameters are JSON (``{"data": x}``; SetVelocity ``{"velocity": [vx, vy, omega], "duration": d}``);
GetFsmId answers ``{"data": id}``.

SetBalanceMode is no FSM switch (the walking controller stays, fsm_id unchanged): it is allowed
in the dynamic state, and SetBalanceMode(0) is the only way out of continuous gait, where the
robot keeps stepping (fsm_mode 1) at zero velocity. So the stop action ``stop_move`` is the two
calls ``stop_calls`` returns: StopMove, then ContinuousGait(false).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Literal

Service = Literal["sport", "loco"]
SERVICES: tuple[Service, ...] = ("sport", "loco")
"""``sport``: ai_sport >= 8.2 (Unitree's SDK today); ``loco``: older firmware."""
STATE_TOPIC = "rt/sportmodestate"

GET_FSM_ID = 7001
GET_FSM_MODE = 7002
GET_BALANCE_MODE = 7003
SET_FSM_ID = 7101
SET_BALANCE_MODE = 7102
SET_STAND_HEIGHT = 7104
SET_VELOCITY = 7105
SET_ARM_TASK = 7106
SET_SPEED_MODE = 7107
API_IDS = frozenset(
    {
        GET_FSM_ID,
        GET_FSM_MODE,
        GET_BALANCE_MODE,
        SET_FSM_ID,
        SET_BALANCE_MODE,
        SET_STAND_HEIGHT,
        SET_VELOCITY,
        SET_ARM_TASK,
        SET_SPEED_MODE,
    }
)
HIGH_STAND = (1 << 32) - 1
"""HighStand sends SetStandHeight(UINT32_MAX), LowStand SetStandHeight(0) (Unitree's SDK)."""
CONTINUOUS_MOVE_S = 864000.0
"""Move(..., continous_move=true) is SetVelocity with this duration in Unitree's SDK."""
ARM_TASKS = {
    0: "wave hand",
    1: "wave hand (turning)",
    2: "shake hand (reach)",
    3: "shake hand (release)",
}
"""SetTaskId's ids as LocoClient's WaveHand(turn_flag) and ShakeHand(stage) send them."""
SPEED_MODES = {0: 1.0, 1: 2.0, 2: 2.7, 3: 3.0}
"""SetSpeedMode: the running mode's top speed (m/s) per mode (seed 004)."""

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
ZERO_TORQUE_FSM = 0
WALK_FSMS = frozenset({500, 501, 801, 802})
ARM_SDK_FSMS = frozenset({4, 500, 501})
"""Seed 004: rt/arm_sdk "can only be used in Locked Stance, Movement Control 1 and Movement
Control 2": lock standing (4) and the walking controller (500, 501 with the 3-dof waist). Run
(801/802) is not named by the seed: refused (the conservative reading)."""
TASK_FSMS = WALK_FSMS | {4}
"""Arm tasks (SetTaskId) and stand height / speed mode need a standing controller."""
STATIC, DYNAMIC = 0, 1


def request_topic(service: str) -> str:
    """The topic a LocoClient writes its requests to (``rt/api/<service>/request``)."""
    return f"rt/api/{service}/request"


def response_topic(service: str) -> str:
    """The topic the service answers on (``rt/api/<service>/response``)."""
    return f"rt/api/{service}/response"


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


_FSM_OPS = {
    "damp": DAMP_FSM,
    "start": 500,
    "stand_up": 4,
    "squat": 2,
    "sit": 3,
    "zero_torque": ZERO_TORQUE_FSM,
    "squat2standup": 706,
    "standup2squat": 706,
    "lie2standup": 702,
}
"""SetFsmId ops, as LocoClient maps them (seed 004's table; ``start`` as this fleet always sent
it: the walking controller 500, where Unitree's Python SDK sends 200, an id seed 004 does not
list)."""


def call_for(
    op: str,
    vx: float = 0.0,
    vy: float = 0.0,
    omega: float = 0.0,
    duration_s: float = 1.0,
    on: bool = False,
    value: float = 0,
) -> Call:
    """The RPC of one fleet op; ``value`` is the ``data`` of ``set_fsm_id``, ``set_stand_height``,
    ``set_speed_mode``, ``set_task_id``, ``wave_hand`` (1: turning), ``shake_hand`` (its
    stage). ValueError for an op with no call."""
    if op in _FSM_OPS:
        fsm = _FSM_OPS[op]
        return Call(SET_FSM_ID, json.dumps({"data": fsm}), fsm != DAMP_FSM)
    if op == "set_fsm_id":
        return Call(SET_FSM_ID, json.dumps({"data": int(value)}), int(value) != DAMP_FSM)
    velocity = {"velocity": [vx, vy, omega], "duration": duration_s}
    data = {
        # SetBalanceMode keeps the FSM: not a mode switch (and 0 is continuous gait's way out).
        "balance_stand": (SET_BALANCE_MODE, {"data": 0}),
        "continuous_gait": (SET_BALANCE_MODE, {"data": 1 if on else 0}),
        "stop_move": (SET_VELOCITY, {"velocity": [0.0, 0.0, 0.0], "duration": 1.0}),
        "set_velocity": (SET_VELOCITY, velocity),
        "move": (SET_VELOCITY, velocity),
        "get_fsm_id": (GET_FSM_ID, {}),
        "get_fsm_mode": (GET_FSM_MODE, {}),
        "get_balance_mode": (GET_BALANCE_MODE, {}),
        "high_stand": (SET_STAND_HEIGHT, {"data": HIGH_STAND}),
        "low_stand": (SET_STAND_HEIGHT, {"data": 0}),
        "set_stand_height": (SET_STAND_HEIGHT, {"data": value}),
        "set_speed_mode": (SET_SPEED_MODE, {"data": int(value)}),
        "set_task_id": (SET_ARM_TASK, {"data": int(value)}),
        "wave_hand": (SET_ARM_TASK, {"data": 1 if value else 0}),
        "shake_hand": (SET_ARM_TASK, {"data": 2 if int(value) == 0 else 3}),
    }.get(op)
    if data is None:
        raise ValueError(f"no LocoClient call for {op!r}")
    api_id, parameter = data
    return Call(api_id, json.dumps(parameter), False)


def stop_calls(action: str) -> tuple[Call, ...]:
    """The calls of one write of a stop action, in order. ``damp``: SetFsmId(1). ``stop_move``:
    StopMove (SetVelocity 0), then ContinuousGait(false) (SetBalanceMode 0): without it a robot
    in continuous gait keeps stepping and the stop never confirms; in balance mode 0 already it
    changes nothing."""
    if action == "damp":
        return (call_for("damp"),)
    if action == "stop_move":
        return (call_for("stop_move"), call_for("balance_stand"))
    raise ValueError(f"no G1 stop action {action!r}")


def refusal(op: str, call: Call, fsm_id: int, fsm_mode: int) -> str | None:
    """Why seed 004 refuses ``op`` in this state, or None: in a dynamic state (fsm_mode 1)
    switching to any mode but damping is not allowed (damping, the fallback, always is). And
    this fleet's own static rules: zero torque (the robot falls) only from damping; arm tasks,
    stand height and speed mode only under a standing controller."""
    zero = op == "zero_torque" or (op == "set_fsm_id" and json.loads(call.parameter)["data"] == 0)
    if zero and fsm_id != DAMP_FSM:
        return (
            f"{op} drops every joint's torque (the robot falls); allowed only from damping "
            f"(fsm 1), and the G1 is in fsm {fsm_id} {fsm_name(fsm_id)}: send damp first"
        )
    if call.api_id in (SET_ARM_TASK, SET_STAND_HEIGHT, SET_SPEED_MODE) and fsm_id not in TASK_FSMS:
        return (
            f"{op} needs a standing controller (fsm 4, 500, 501, 801, 802), and the G1 is in "
            f"fsm {fsm_id} {fsm_name(fsm_id)}: send start first"
        )
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
