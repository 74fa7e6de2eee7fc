"""Translate the D1 commands the agent sent into detector inputs (targets, mode, torque)."""

from __future__ import annotations

from fleet.contact.detector import ContactDetector
from fleet.d1 import protocol as p
from fleet.d1.limits import JOINT_COUNT


def feed_command(detector: ContactDetector, command: p.Command, now_s: float) -> None:
    """Tell ``detector`` what ``command`` (written to the arm at ``now_s``) asks the arm to do."""
    if isinstance(command, p.SetAllAngles):
        detector.on_targets(dict(enumerate(command.angles_deg)), command.mode, now_s)
    elif isinstance(command, p.SetJointAngle):
        detector.on_targets({command.joint: command.angle_deg}, None, now_s)
    elif isinstance(command, p.ReturnToZero):
        detector.on_targets(dict.fromkeys(range(JOINT_COUNT), 0.0), 1, now_s)
    elif isinstance(command, p.SetJointTorque):
        detector.on_torque(command.joint, command.enable)
    elif isinstance(command, p.SetAllTorque):
        detector.on_torque(None, command.mode > 0)
    elif isinstance(command, p.SetPower):
        detector.set_tracking(command.on)
