"""The G1's key-space payloads (``fleet/<fleet>/g1/<id>/...``), msgspec Structs."""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta, Struct

from fleet.wire.messages import Count, DeviceCommand, StampNs, Text
from fleet.wire.messages import DeviceRelease as Release

Speed = Annotated[float, Meta(ge=-10.0, le=10.0)]
JointQ = Annotated[float, Meta(ge=-10.0, le=10.0)]
"""A G1 joint's angle (rad): its limits are within +-3.1, 10 bounds garbage, never a reading."""


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
    arm_phase: Literal["off", "engaging", "on", "holding", "releasing"] = "off"
    """The rt/arm_sdk stream (``fleet/g1/arms.py``)."""
    arm_weight: float | None = None
    """The weight the robot holds as far as the agent knows: its newest rt/arm_sdk message's,
    or another writer's seen on rt/arm_sdk (0: the robot's own controller has the arms; None:
    unknown, e.g. after the agent's restart; the next stream starts at 1 on the measured pose)."""
    arm_released: Text | None = None
    """Why the arms were last released (an ``arm_release``, the agent's exit, an FSM that
    forbids rt/arm_sdk, or a stop with ``arm_on_stop = "release"``)."""
    arm_held: Text | None = None
    """Why the arms are held (weight kept, pose frozen): a stop, the watchdog, the lease."""
    watched_by: Text | None = None
    """The commander whose heartbeat the G1's watchdog watches now (None: none)."""


class G1LowState(Struct, frozen=True):
    """``g1/<id>/lowstate``: the newest valid ``rt/lowstate`` (CRC and values checked) at
    ``relay_hz``: the 29 joints' positions (rad, Unitree's motor order) and the IMU."""

    stamp_ns: StampNs
    q_rad: Annotated[list[JointQ], Meta(min_length=29, max_length=29)]
    """Bounded here, so every consumer (viewer, Foxglove, recorder, replay) gets 29 finite
    angles or a PayloadError: a malformed recorded lowstate is counted, never drawn."""
    imu_rpy: Annotated[
        list[Annotated[float, Meta(ge=-10.0, le=10.0)]], Meta(min_length=3, max_length=3)
    ]
    imu_quaternion: Annotated[
        list[Annotated[float, Meta(ge=-2.0, le=2.0)]], Meta(min_length=4, max_length=4)
    ]
    tick: int
    bad_samples: Count


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


class GetFsmMode(_G1Command, tag="get_fsm_mode", kw_only=True):
    """GetFsmMode: the reply's ``result`` is 0 (standing) or 1 (moving)."""


class GetBalanceMode(_G1Command, tag="get_balance_mode", kw_only=True):
    """GetBalanceMode: the reply's ``result`` is 0 (balance stand) or 1 (continuous gait)."""


class Squat(_G1Command, tag="squat", kw_only=True):
    """SetFsmId(2): position-control squat."""


class Sit(_G1Command, tag="sit", kw_only=True):
    """SetFsmId(3): position-control sit down."""


class ZeroTorque(_G1Command, tag="zero_torque", kw_only=True):
    """SetFsmId(0): no torque at all (the robot falls): allowed only from damping."""


class Squat2StandUp(_G1Command, tag="squat2standup", kw_only=True):
    """SetFsmId(706): from the squat, stand up."""


class StandUp2Squat(_G1Command, tag="standup2squat", kw_only=True):
    """SetFsmId(706): from standing, squat."""


class Lie2StandUp(_G1Command, tag="lie2standup", kw_only=True):
    """SetFsmId(702): from lying, stand up."""


class SetFsmId(_G1Command, tag="set_fsm_id", kw_only=True):
    """SetFsmId(fsm_id): an id of seed 004's table."""

    fsm_id: Annotated[int, Meta(ge=0, le=1000)]


class HighStand(_G1Command, tag="high_stand", kw_only=True):
    """SetStandHeight(UINT32_MAX): the highest stand."""


class LowStand(_G1Command, tag="low_stand", kw_only=True):
    """SetStandHeight(0): the lowest stand."""


class SetStandHeight(_G1Command, tag="set_stand_height", kw_only=True):
    """SetStandHeight(height): as Unitree's SDK passes it (0 lowest .. 4294967295 highest)."""

    height: Annotated[float, Meta(ge=0.0, le=4294967295.0)]


class SetSpeedMode(_G1Command, tag="set_speed_mode", kw_only=True):
    """SetSpeedMode(mode): the running mode's top speed, 0: 1.0, 1: 2.0, 2: 2.7, 3: 3.0 m/s."""

    mode: Annotated[int, Meta(ge=0, le=3)]


class Move(_G1Command, tag="move", kw_only=True):
    """Move(vx, vy, vyaw, continuous): SetVelocity for 1 s, or with ``continuous`` for the SDK's
    864000 s (refused unless the inventory's ``allow_continuous_move``; a fleet stop ends it)."""

    vx: Speed = 0.0
    vy: Speed = 0.0
    vyaw: Speed = 0.0
    continuous: bool = False


class SetTaskId(_G1Command, tag="set_task_id", kw_only=True):
    """SetTaskId(task_id): an upper-limb task of the loco service (0-3: wave, shake)."""

    task_id: Annotated[int, Meta(ge=0, le=3)]


class WaveHand(_G1Command, tag="wave_hand", kw_only=True):
    """WaveHand(turn): SetTaskId(1 if turn else 0)."""

    turn: bool = False


class ShakeHand(_G1Command, tag="shake_hand", kw_only=True):
    """ShakeHand(stage): SetTaskId(2) to reach out (stage 0), SetTaskId(3) to let go (1)."""

    stage: Annotated[int, Meta(ge=0, le=1)] = 0


class ArmTarget(_G1Command, tag="arm_target", kw_only=True):
    """The waist and arms (motors 12-28, rad) as a target of the rt/arm_sdk stream: the agent
    engages (weight 1 on the measured pose, or 0 -> 1 when the robot's weight is known to be 0),
    then moves the commanded pose towards it at ``speed_rad_s`` (the inventory's
    ``arm_speed_rad_s`` when None). Renew it within the lease, else held (``arm_on_stop``)."""

    q_rad: Annotated[list[JointQ], Meta(min_length=17, max_length=17)]
    speed_rad_s: Annotated[float, Meta(gt=0.0, le=10.0)] | None = None


class ArmRelease(_G1Command, tag="arm_release", kw_only=True):
    """Give the arms back to the robot's own controller (weight 1 -> 0 over ``arm_release_s``);
    with no stream of its own and the robot's weight unknown, the agent starts one at weight 1
    on the measured pose to ramp it down."""


G1Command = (
    Damp
    | Start
    | StandUp
    | BalanceStand
    | ContinuousGait
    | StopMove
    | SetVelocity
    | GetFsmId
    | GetFsmMode
    | GetBalanceMode
    | Squat
    | Sit
    | ZeroTorque
    | Squat2StandUp
    | StandUp2Squat
    | Lie2StandUp
    | SetFsmId
    | HighStand
    | LowStand
    | SetStandHeight
    | SetSpeedMode
    | Move
    | SetTaskId
    | WaveHand
    | ShakeHand
    | ArmTarget
    | ArmRelease
    | Release
)
OPS: dict[type, str] = {cls: cls.__struct_config__.tag for cls in G1Command.__args__}
READS = (GetFsmId, GetFsmMode, GetBalanceMode)
"""Calls that only ask (allowed under a stop, never set the robot moving)."""
