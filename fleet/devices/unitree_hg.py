"""The ``unitree_hg`` motor and IMU types that the G1 and the Dex1-1 (``hg`` family) share.

``unitree_hg::msg::dds_::MotorCmd_``, ``MotorState_`` and ``IMUState_`` as Unitree's unitree_sdk2
IDL defines them: one definition, so the two kinds can never drift apart on the wire (CDR has no
field names: one field out of place is a different message). The G1's ``LowCmd_`` / ``LowState_``
(``fleet.g1.idl``) and the Dex1-1's ``HandCmd_`` / ``HandState_`` (``fleet.dex1.idl``) embed them.
Defaults are the IDL's zeros, as Unitree's generated types have (a level IMU is the caller's
choice: the simulated G1 sets its quaternion to identity).

(No ``from __future__ import annotations``: CycloneDDS resolves the field types at run time.)
"""

from dataclasses import dataclass, field

import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct


@dataclass
@annotate.final
class MotorCmd_(IdlStruct, typename="unitree_hg::msg::dds_::MotorCmd_"):  # noqa: N801
    """One motor's command: mode (1 enabled), q (rad; on index 29 of the G1's rt/arm_sdk the
    weight), dq, tau, kp, kd."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    tau: types.float32 = 0.0
    kp: types.float32 = 0.0
    kd: types.float32 = 0.0
    reserve: types.uint32 = 0


@dataclass
@annotate.final
class MotorState_(IdlStruct, typename="unitree_hg::msg::dds_::MotorState_"):  # noqa: N801
    """One motor's state (q in rad)."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    ddq: types.float32 = 0.0
    tau_est: types.float32 = 0.0
    temperature: types.array[types.int16, 2] = field(default_factory=lambda: [0, 0])
    vol: types.float32 = 0.0
    sensor: types.array[types.uint32, 2] = field(default_factory=lambda: [0, 0])
    motorstate: types.uint32 = 0
    reserve: types.array[types.uint32, 4] = field(default_factory=lambda: [0, 0, 0, 0])


@dataclass
@annotate.final
class IMUState_(IdlStruct, typename="unitree_hg::msg::dds_::IMUState_"):  # noqa: N801
    """An IMU: quaternion (w, x, y, z), gyroscope, accelerometer, rpy (rad); zeros on a Dex1-1."""

    quaternion: types.array[types.float32, 4] = field(default_factory=lambda: [0.0] * 4)
    gyroscope: types.array[types.float32, 3] = field(default_factory=lambda: [0.0] * 3)
    accelerometer: types.array[types.float32, 3] = field(default_factory=lambda: [0.0] * 3)
    rpy: types.array[types.float32, 3] = field(default_factory=lambda: [0.0] * 3)
    temperature: types.int16 = 0
