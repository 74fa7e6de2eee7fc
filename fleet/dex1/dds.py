"""The Dex1-1's DDS side: QoS (seed 003: commands reliable, state best effort) and the one
function that builds a command sample of either family.

(No ``from __future__ import annotations``: CycloneDDS resolves IDL types at run time.)
"""

from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.util import duration

from fleet.dex1 import idl
from fleet.dex1.codec import Target

# Commands: reliable (the gripper's reader is reliable, seed 003), keep-last 4: a command is a
# position, only the newest matters once it is written.
COMMAND_WRITER_QOS = Qos(
    Policy.Reliability.Reliable(duration(milliseconds=100)),
    Policy.History.KeepLast(4),
    Policy.Durability.Volatile,
)
COMMAND_READER_QOS = COMMAND_WRITER_QOS
# State: best effort at 200-500 Hz; the agent takes every sample, keep-last 64 absorbs a
# scheduling gap of 0.13 s at 500 Hz without growing.
STATE_READER_QOS = Qos(
    Policy.Reliability.BestEffort,
    Policy.History.KeepLast(64),
    Policy.Durability.Volatile,
)
STATE_WRITER_QOS = Qos(
    Policy.Reliability.BestEffort,
    Policy.History.KeepLast(1),
    Policy.Durability.Volatile,
)


def command_sample(family: str, target: Target) -> Any:
    """The DDS command of ``family`` for ``target`` (mode 0: position, one motor)."""
    if family == "hg":
        motor = idl.HgMotorCmd_(mode=0, q=target.q_rad, tau=target.tau, kp=target.kp, kd=target.kd)
        return idl.HandCmd_(motor_cmd=[motor])
    cmd = idl.GoMotorCmd_(mode=0, q=target.q_rad, tau=target.tau, kp=target.kp, kd=target.kd)
    return idl.MotorCmds_(cmds=[cmd])


def target_of(family: str, sample: Any) -> Target | None:
    """The first motor target of a command sample (the simulator's side), or None."""
    motors = sample.motor_cmd if family == "hg" else sample.cmds
    if not motors:
        return None
    m = motors[0]
    return Target(q_rad=float(m.q), tau=float(m.tau), kp=float(m.kp), kd=float(m.kd))
