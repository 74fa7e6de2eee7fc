"""Contact detector thresholds: the inventory's ``contact`` table (``[defaults.contact]`` or
``[arms.<id>.contact]``, with ``arm`` and ``gripper`` sub-tables).

The defaults are justified by the benchmark (``bench/contact.py``, docs/results/contact.md),
which runs them on every plausible arm dynamics family, uncalibrated and calibrated,
with feedback noise and jitter. Method 2's figures follow from the plausible range itself.
"""

from __future__ import annotations

from typing import Literal

import msgspec
from msgspec import Struct

MAX_BUFFER_SIZE = 100_000
"""Samples kept per joint, at most (about 3 hours at 10 Hz)."""
MAX_REVERSALS = 1000
"""Oscillation reversals, at most (more could never fit in a window of feedback)."""

Method = Literal["tracking", "stall", "status", "oscillation", "model"]
METHODS: tuple[Method, ...] = ("tracking", "stall", "status", "oscillation", "model")
"""Methods 1..5 of the plan: tracking error, velocity stall (with 1), ``error_status``,
oscillation (servo hunting), expected-versus-actual against the arm's smoothing model."""


class Thresholds(Struct, frozen=True, forbid_unknown_fields=True):
    """Thresholds for one kind of joint (the six arm joints, or the gripper)."""

    suspect_deg: float = 2.0
    """No method but ``status`` fires while the tracking error |target - measured| is below
    this: a joint (nearly) on its target is not in contact, whatever a model says."""
    confirm_deg: float = 5.0
    """Method 1: tracking error that, held for ``confirm_s``, confirms a contact."""
    stall_error_deg: float = 3.0
    """Method 2: tracking error above this ..."""
    stall_velocity_deg_s: float = 10.0
    """... while the joint progresses towards its target slower than this over
    ``stall_window_s`` (and slower than error / ``stall_lag_s``): half the slowest plausible
    D1 speed limit (20 deg/s). The plan's 0.1 deg/s is below the feedback noise (0.1 deg over
    0.1 s is 1 deg/s) and would miss a joint creeping into a compliant obstacle."""
    stall_lag_s: float = 1.0
    """Twice the slowest plausible first-order lag (0.5 s): a free joint with error e moves at
    least e / 0.5 s."""
    stall_window_s: float = 0.3
    """The window over which method 2 measures progress: the dead time (up to 0.1 s) and a
    second-order servo's start must not look like a stall."""
    model_error_deg: float = 1.0
    """Method 5: |measured - predicted by the smoothing model| above this ..."""
    timing_tolerance_s: float = 0.04
    """... plus the predicted speed times this (feedback stamps are late by jitter and
    latency: 30 ms of jitter plus a few ms of transport in the benchmark)."""
    oscillation_step_deg: float = 0.3
    """Method 4: a reversal counts when both steps around it exceed this."""
    oscillation_reversals: int = 4
    """Method 4: reversals within ``oscillation_window_s`` while the target is unchanged."""
    oscillation_window_s: float = 1.2
    confirm_s: float = 0.05
    """A method must fire continuously this long (two consecutive feedback samples) to
    confirm; with 0 (one sample) the benchmark showed 47 false alarms in free motion. A trusted
    model (method 5) confirms on one *corroborated* sample instead (``detector.py``)."""
    release_deg: float = 1.5
    """A confirmed contact releases when no method fires and the tracking error is below this
    (hysteresis: far below the confirming thresholds) ..."""
    release_s: float = 0.3
    """... for this long; RELEASED becomes FREE after another ``release_s`` of quiet."""
    force_limit_deg: float | None = 8.0
    """Force limiting by position: a confirmed contact whose tracking error passes this makes
    the agent retract the joint's target to the measured angle (None: never)."""


def _gripper() -> Thresholds:
    # The gripper closes on objects by design: a grip may hold some error (the servo squeezes),
    # so it is confirmed later and never force-limited below 20 deg of squeeze.
    return Thresholds(
        suspect_deg=3.0,
        confirm_deg=6.0,
        stall_error_deg=4.0,
        model_error_deg=2.0,
        confirm_s=0.05,
        force_limit_deg=20.0,
    )


class ContactConfig(Struct, frozen=True, forbid_unknown_fields=True):
    """The detector's configuration for one arm."""

    enabled: bool = True
    methods: list[Method] = msgspec.field(
        default_factory=lambda: ["stall", "status", "oscillation", "model"]
    )
    """Methods whose confirmation confirms a contact (the default combination). ``tracking``
    alone confirms on large commanded steps: see the benchmark."""
    arm: Thresholds = msgspec.field(default_factory=Thresholds)
    gripper: Thresholds = msgspec.field(default_factory=_gripper)
    buffer_size: int = 64
    """Samples kept per joint (about 6 s at 10 Hz)."""

    def for_joint(self, joint: int) -> Thresholds:
        """The thresholds of wire joint ``joint`` (6 = gripper)."""
        return self.gripper if joint == 6 else self.arm


def check_config(config: ContactConfig) -> str | None:
    """A description of what is wrong with ``config``, or None when it is usable."""
    for name, t in (("arm", config.arm), ("gripper", config.gripper)):
        if not 0 < t.release_deg < t.suspect_deg <= t.confirm_deg:
            return f"{name}: need 0 < release_deg < suspect_deg <= confirm_deg"
        positive = (
            t.stall_error_deg,
            t.stall_velocity_deg_s,
            t.stall_lag_s,
            t.stall_window_s,
            t.model_error_deg,
            t.release_s,
        )
        if min(positive) <= 0 or t.confirm_s < 0:
            return f"{name}: thresholds must be positive"
        if not 2 <= t.oscillation_reversals <= MAX_REVERSALS:
            return f"{name}: oscillation_reversals must be 2..{MAX_REVERSALS}"
        if t.force_limit_deg is not None and t.force_limit_deg <= t.suspect_deg:
            return f"{name}: force_limit_deg must exceed suspect_deg (or be omitted)"
    if not 8 <= config.buffer_size <= MAX_BUFFER_SIZE:
        # The upper bound also keeps a file's 400-digit size out of deque(maxlen=...), which
        # raises OverflowError in the agent.
        return f"buffer_size must be 8..{MAX_BUFFER_SIZE}"
    return None
