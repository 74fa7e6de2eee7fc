"""The G1 high-level service's DDS types, with Unitree's type names on the wire.

``unitree_hg::msg::dds_::SportModeState_`` (seed 004, firmware 1.5.1 and later) and the RPC
envelope of unitree_sdk2 (``unitree_api::msg::dds_::Request_`` / ``Response_``): a request
carries an identity (a request id and the API id), a lease and a policy, and a JSON parameter
string; the response echoes the identity, with a status code and a JSON data string. The
field layout follows Unitree's IDL (read from unitree_sdk2 / unitree_sdk2_python). The motor
and IMU types shared with the Dex1-1 live in ``fleet.devices.unitree_hg``.

(No ``from __future__ import annotations``: CycloneDDS resolves IDL types at run time.)
"""

from dataclasses import dataclass, field

import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct

from fleet.devices.unitree_hg import IMUState_, MotorCmd_, MotorState_

__all__ = [
    "IMUState_",
    "LowCmd_",
    "LowState_",
    "MotorCmd_",
    "MotorState_",
    "Request_",
    "Response_",
    "SportModeState_",
]


@dataclass
@annotate.final
class SportModeState_(IdlStruct, typename="unitree_hg::msg::dds_::SportModeState_"):  # noqa: N801
    """``rt/sportmodestate``: the FSM id, its mode (0 static, 1 dynamic), the arm task."""

    fsm_id: types.uint32 = 0
    fsm_mode: types.uint32 = 0
    task_id: types.uint32 = 0
    task_time: types.float32 = 0.0


@dataclass
@annotate.final
class RequestIdentity_(IdlStruct, typename="unitree_api::msg::dds_::RequestIdentity_"):  # noqa: N801
    """Request id (unique per client) and API id."""

    id: types.int64 = 0
    api_id: types.int64 = 0


@dataclass
@annotate.final
class RequestLease_(IdlStruct, typename="unitree_api::msg::dds_::RequestLease_"):  # noqa: N801
    """The lease id (0: no lease; the loco service runs without one)."""

    id: types.int64 = 0


@dataclass
@annotate.final
class RequestPolicy_(IdlStruct, typename="unitree_api::msg::dds_::RequestPolicy_"):  # noqa: N801
    """Priority, and whether the caller wants no reply."""

    priority: types.int32 = 0
    noreply: bool = False


@dataclass
@annotate.final
class RequestHeader_(IdlStruct, typename="unitree_api::msg::dds_::RequestHeader_"):  # noqa: N801
    """The request's header."""

    identity: RequestIdentity_ = field(default_factory=RequestIdentity_)
    lease: RequestLease_ = field(default_factory=RequestLease_)
    policy: RequestPolicy_ = field(default_factory=RequestPolicy_)


@dataclass
@annotate.final
class Request_(IdlStruct, typename="unitree_api::msg::dds_::Request_"):  # noqa: N801
    """``rt/api/<service>/request``."""

    header: RequestHeader_ = field(default_factory=RequestHeader_)
    parameter: str = ""
    binary: types.sequence[types.uint8] = field(default_factory=list)


@dataclass
@annotate.final
class ResponseStatus_(IdlStruct, typename="unitree_api::msg::dds_::ResponseStatus_"):  # noqa: N801
    """0, or an error code of seed 001's table."""

    code: types.int32 = 0


@dataclass
@annotate.final
class ResponseHeader_(IdlStruct, typename="unitree_api::msg::dds_::ResponseHeader_"):  # noqa: N801
    """The response's header: the request's identity and the status."""

    identity: RequestIdentity_ = field(default_factory=RequestIdentity_)
    status: ResponseStatus_ = field(default_factory=ResponseStatus_)


@dataclass
@annotate.final
class Response_(IdlStruct, typename="unitree_api::msg::dds_::Response_"):  # noqa: N801
    """``rt/api/<service>/response``."""

    header: ResponseHeader_ = field(default_factory=ResponseHeader_)
    data: str = ""
    binary: types.sequence[types.uint8] = field(default_factory=list)


# ---------------------------------------------------------------------- low level (rt/arm_sdk)


@dataclass
@annotate.final
class LowCmd_(IdlStruct, typename="unitree_hg::msg::dds_::LowCmd_"):  # noqa: N801
    """``rt/arm_sdk`` (seed 004: indices 12-28 the waist and arms, 29 the weight), CRC-sealed."""

    mode_pr: types.uint8 = 0
    mode_machine: types.uint8 = 0
    motor_cmd: types.array[MotorCmd_, 35] = field(default_factory=lambda: [MotorCmd_()] * 35)
    reserve: types.array[types.uint32, 4] = field(default_factory=lambda: [0, 0, 0, 0])
    crc: types.uint32 = 0


@dataclass
@annotate.final
class LowState_(IdlStruct, typename="unitree_hg::msg::dds_::LowState_"):  # noqa: N801
    """``rt/lowstate``: the 29 (of 35) motors' states and the IMU, CRC-sealed."""

    version: types.array[types.uint32, 2] = field(default_factory=lambda: [0, 0])
    mode_pr: types.uint8 = 0
    mode_machine: types.uint8 = 0
    tick: types.uint32 = 0
    imu_state: IMUState_ = field(default_factory=IMUState_)
    motor_state: types.array[MotorState_, 35] = field(default_factory=lambda: [MotorState_()] * 35)
    wireless_remote: types.array[types.uint8, 40] = field(default_factory=lambda: [0] * 40)
    reserve: types.array[types.uint32, 4] = field(default_factory=lambda: [0, 0, 0, 0])
    crc: types.uint32 = 0
