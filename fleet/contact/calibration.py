"""An arm's calibration file: each joint's measured response per smoothing mode, written by
``fleet calibrate`` (``fleet/cli/calibrate.py``, the fit in ``fit.py``) and read by the agent's
contact detector (method 5's model). JSON; the inventory names the file per arm
(``calibration``, default ``calibration/<arm>.json`` next to the inventory).
"""

from __future__ import annotations

from pathlib import Path

import msgspec
from msgspec import Struct

from fleet.contact.dynamics import ArmDynamics, ModeDynamics
from fleet.files import FileReadError, plausible, read_regular

VERSION = 1


class CalibrationError(ValueError):
    """A calibration file that cannot be used (its path and the problem in the message)."""


class JointCalibration(Struct, frozen=True, forbid_unknown_fields=True):
    """One joint's fitted response, and how well the fit matched its steps (RMS, deg)."""

    joint: int
    mode0: ModeDynamics
    mode1: ModeDynamics
    rms_deg: float = 0.0
    timing_rms_deg: float | None = None
    """The fit's RMS less what late report stamps explain (``fit.timing_rms``); method 5's
    slack is 3x this (3x ``rms_deg`` in files written before it existed)."""

    def error_deg(self) -> float:
        """The fit's own error that method 5's tolerance must cover on top of its timing."""
        return self.rms_deg if self.timing_rms_deg is None else self.timing_rms_deg

    def dynamics(self) -> ArmDynamics:
        """Both modes as the predictor takes them."""
        return ArmDynamics(mode0=self.mode0, mode1=self.mode1)


class Calibration(Struct, frozen=True, forbid_unknown_fields=True):
    """A calibration of one arm. Joints that were not calibrated are absent."""

    arm: str
    stamp_ns: int
    joints: list[JointCalibration]
    version: int = VERSION
    routine: str = ""
    """What was run (step sizes, modes), for the record."""
    feedback_jitter_s: float = 0.0
    """How irregular the arm's feedback came during the routine (twice the 95th percentile of the
    deviation of report intervals from their median): method 5's timing tolerance is at least
    this (a late-stamped report of a moving joint lags the model by speed x lateness)."""

    def joint(self, joint: int) -> JointCalibration | None:
        """The calibration of wire joint ``joint``, None when it was not calibrated."""
        return next((c for c in self.joints if c.joint == joint), None)

    def complete(self, joints: int = 7) -> bool:
        """True when every joint has a calibration."""
        return all(self.joint(j) is not None for j in range(joints))


MAX_CALIBRATION_BYTES = 64 * 1024
"""A calibration of 7 joints is about 3 KB."""
MAX_RMS_DEG = 20.0
"""A fit worse than this is no model at all (good fits measure 0.1-2 deg)."""
MAX_JITTER_S = 0.5


def load_calibration(path: Path) -> Calibration | None:
    """The calibration in ``path``; None when there is no such file. Only a regular file of
    at most ``MAX_CALIBRATION_BYTES`` is read (a named pipe would block its reader); every
    figure must be finite and plausible (``rms_deg = 1e300`` switched the model method off)."""
    try:
        data = read_regular(path, MAX_CALIBRATION_BYTES, "calibration")
    except FileNotFoundError:
        return None
    except FileReadError as exc:
        raise CalibrationError(f"{exc}; re-run fleet calibrate") from None
    try:
        calibration = msgspec.json.decode(data, type=Calibration)
    except (msgspec.DecodeError, RecursionError, UnicodeDecodeError) as exc:
        raise CalibrationError(
            f"{path}: not a calibration file ({exc}); re-run fleet calibrate"
        ) from None
    problem = implausible(calibration)
    if problem is not None:
        raise CalibrationError(f"{path}: {problem}; re-run fleet calibrate")
    return calibration


def implausible(calibration: Calibration) -> str | None:
    """What in ``calibration`` is not finite or out of its plausible range, or None."""
    if not plausible(calibration.feedback_jitter_s, 0.0, MAX_JITTER_S):
        return f"feedback_jitter_s must be finite, 0..{MAX_JITTER_S}"
    seen = set()
    for joint in calibration.joints:
        if not 0 <= joint.joint <= 6 or joint.joint in seen:
            return f"joint {joint.joint}: joints are 0..6, each once"
        seen.add(joint.joint)
        for name, mode in (("mode0", joint.mode0), ("mode1", joint.mode1)):
            problem = mode.problem()
            if problem is not None:
                return f"joint {joint.joint} {name}: {problem}"
        timing = joint.timing_rms_deg
        if not plausible(joint.rms_deg, 0.0, MAX_RMS_DEG) or not (
            timing is None or plausible(timing, 0.0, MAX_RMS_DEG)
        ):
            return (
                f"joint {joint.joint}: rms_deg and timing_rms_deg must be finite, 0..{MAX_RMS_DEG}"
            )
    return None


def save_calibration(path: Path, calibration: Calibration) -> None:
    """Write ``calibration`` to ``path`` (atomically: a reader never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(path.suffix + ".partial")
    partial.write_bytes(msgspec.json.format(msgspec.json.encode(calibration)) + b"\n")
    partial.replace(path)


def merge(old: Calibration | None, new: Calibration) -> Calibration:
    """``new`` over ``old`` joint by joint (``fleet calibrate --joint J`` keeps the others)."""
    if old is None:
        return new
    fresh = {c.joint for c in new.joints}
    kept = [c for c in old.joints if c.joint not in fresh]
    joints = sorted([*kept, *new.joints], key=lambda c: c.joint)
    return msgspec.structs.replace(new, joints=joints)
