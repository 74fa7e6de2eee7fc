"""The Dex1-1's DDS types, with Unitree's type names on the wire.

Two families, as the seed describes (003) and Unitree's unitree_sdk2 IDL defines them:
- ``hg``: ``unitree_hg::msg::dds_::HandCmd_`` / ``HandState_`` (with ``MotorCmd_`` /
  ``MotorState_``, ``PressSensorState_``, ``IMUState_``), as the G1's hands use;
- ``go``: ``unitree_go::msg::dds_::MotorCmds_`` / ``MotorStates_`` (with ``MotorCmd_`` /
  ``MotorState_``), what Unitree's own Dex1-1 service and teleoperation publish.
Field order and types follow Unitree's IDL exactly (CDR has no field names: one field out of
place is a different message). Every struct is ``@final``, as Unitree's generated types are.
The ``unitree_hg`` motor and IMU types are the G1's too: one definition in
``fleet.devices.unitree_hg`` (named ``Hg...`` here beside the ``unitree_go`` ones).

(No ``from __future__ import annotations``: CycloneDDS resolves the field types at run time.)
"""

from dataclasses import dataclass, field

import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct

from fleet.devices.unitree_hg import IMUState_ as HgIMUState_
from fleet.devices.unitree_hg import MotorCmd_ as HgMotorCmd_
from fleet.devices.unitree_hg import MotorState_ as HgMotorState_

# ----------------------------------------------------------------------------- unitree_hg


@dataclass
@annotate.final
class HandCmd_(IdlStruct, typename="unitree_hg::msg::dds_::HandCmd_"):  # noqa: N801
    """``unitree_hg::msg::dds_::HandCmd_``: one motor command for a Dex1-1."""

    motor_cmd: types.sequence[HgMotorCmd_] = field(default_factory=list)
    reserve: types.array[types.uint32, 4] = field(default_factory=lambda: [0, 0, 0, 0])


@dataclass
@annotate.final
class PressSensorState_(  # noqa: N801
    IdlStruct, typename="unitree_hg::msg::dds_::PressSensorState_"
):
    """``unitree_hg::msg::dds_::PressSensorState_`` (empty on a Dex1-1)."""

    pressure: types.array[types.float32, 12] = field(default_factory=lambda: [0.0] * 12)
    temperature: types.array[types.float32, 12] = field(default_factory=lambda: [0.0] * 12)
    lost: types.uint32 = 0
    reserve: types.uint32 = 0


@dataclass
@annotate.final
class HandState_(IdlStruct, typename="unitree_hg::msg::dds_::HandState_"):  # noqa: N801
    """``unitree_hg::msg::dds_::HandState_``: one motor state for a Dex1-1."""

    motor_state: types.sequence[HgMotorState_] = field(default_factory=list)
    press_sensor_state: types.sequence[PressSensorState_] = field(default_factory=list)
    imu_state: HgIMUState_ = field(default_factory=HgIMUState_)
    power_v: types.float32 = 0.0
    power_a: types.float32 = 0.0
    system_v: types.float32 = 0.0
    device_v: types.float32 = 0.0
    error: types.array[types.uint32, 2] = field(default_factory=lambda: [0, 0])
    reserve: types.array[types.uint32, 2] = field(default_factory=lambda: [0, 0])


# ----------------------------------------------------------------------------- unitree_go


@dataclass
@annotate.final
class GoMotorCmd_(IdlStruct, typename="unitree_go::msg::dds_::MotorCmd_"):  # noqa: N801
    """``unitree_go::msg::dds_::MotorCmd_``."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    tau: types.float32 = 0.0
    kp: types.float32 = 0.0
    kd: types.float32 = 0.0
    reserve: types.array[types.uint32, 3] = field(default_factory=lambda: [0, 0, 0])


@dataclass
@annotate.final
class MotorCmds_(IdlStruct, typename="unitree_go::msg::dds_::MotorCmds_"):  # noqa: N801
    """``unitree_go::msg::dds_::MotorCmds_``."""

    cmds: types.sequence[GoMotorCmd_] = field(default_factory=list)


@dataclass
@annotate.final
class GoMotorState_(IdlStruct, typename="unitree_go::msg::dds_::MotorState_"):  # noqa: N801
    """``unitree_go::msg::dds_::MotorState_``."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    ddq: types.float32 = 0.0
    tau_est: types.float32 = 0.0
    q_raw: types.float32 = 0.0
    dq_raw: types.float32 = 0.0
    ddq_raw: types.float32 = 0.0
    temperature: types.uint8 = 0
    lost: types.uint32 = 0
    reserve: types.array[types.uint32, 2] = field(default_factory=lambda: [0, 0])


@dataclass
@annotate.final
class MotorStates_(IdlStruct, typename="unitree_go::msg::dds_::MotorStates_"):  # noqa: N801
    """``unitree_go::msg::dds_::MotorStates_``."""

    states: types.sequence[GoMotorState_] = field(default_factory=list)


FAMILIES = {"hg": (HandCmd_, HandState_), "go": (MotorCmds_, MotorStates_)}
"""family -> (command type, state type)."""
