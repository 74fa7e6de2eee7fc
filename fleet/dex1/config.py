"""A Dex1-1 gripper's inventory entry: ``[grippers.<id>]``."""

from __future__ import annotations

import math
from typing import Literal

from fleet.d1 import topics
from fleet.devices.base import DeviceBase

Family = Literal["hg", "go"]
Side = Literal["left", "right"]


class GripperConfig(DeviceBase, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """One Dex1-1 gripper. Topics: ``<topic_prefix>/<side>/cmd<topic_suffix>`` and
    ``<topic_prefix>/<side>/state<topic_suffix>`` (default ``rt/dex1/left/cmd``)."""

    family: Family = "go"
    """``go``: ``MotorCmds_``/``MotorStates_`` (Unitree's Dex1-1 service, teleoperation);
    ``hg``: ``HandCmd_``/``HandState_``."""
    side: Side = "left"
    topic_prefix: str = "rt/dex1"
    topic_suffix: str = ""
    mount: str = ""
    """The arm it is mounted on (the viewer draws it there), or ``""``: it stands alone."""
    relay_hz: float = 50.0
    """Zenoh state rate: the newest DDS sample at this rate (the gripper sends 200-500 Hz)."""
    q_min_rad: float = 0.0
    q_max_rad: float = 2.0 * math.pi
    tau_max: float = 1.0
    """Effort (``MotorCmd_.tau``) accepted up to this."""
    kp_max: float = 10.0
    kd_max: float = 1.0
    kp: float = 5.0
    """Position gain sent when a command gives none (Unitree's teleoperation sends 5 and 0.05;
    seed 003 says the Dex1-1 ignores the gains)."""
    kd: float = 0.05
    tau: float = 0.0
    """Effort sent when a command gives none: 0, as seed 003 ("unused, set to 0.0") and
    Unitree's teleoperation (``tau = 0.0``) send it; the gripper is position controlled."""
    grip_error_rad: float = 0.3
    """Grip: the position lags a closing target by more than this ..."""
    grip_speed_rad_s: float = 0.2
    """... while it moves slower than this ..."""
    grip_confirm_s: float = 0.04
    """... for this long (20 samples at 500 Hz)."""
    release_error_rad: float = 0.1
    """A grip ends when the error stays below this (or the target opens) for release_s."""
    release_s: float = 0.1
    max_speed_rad_s: float = 20.0
    """A position that moved faster than this since the last one is a sensor fault or a
    forgery, dropped (``diag.implausible_feedback``) unless it persists: a full stroke in
    0.3 s, about three times the simulator's ``sim_speed_rad_s``."""
    sim_rate_hz: float = 500.0
    """Simulator only: its state rate."""
    sim_speed_rad_s: float = 6.0
    """Simulator only: how fast its fingers move."""
    sim_object_rad: float | None = None
    """Simulator only: an object between the fingers that stops them closing below this."""

    @property
    def cmd_topic(self) -> str:
        """The DDS command topic."""
        return f"{self.topic_prefix}/{self.side}/cmd{self.topic_suffix}"

    @property
    def state_topic(self) -> str:
        """The DDS state topic."""
        return f"{self.topic_prefix}/{self.side}/state{self.topic_suffix}"


def check_gripper(config: GripperConfig) -> str | None:
    """Why ``config`` is unusable, or None."""
    for topic in (config.cmd_topic, config.state_topic):
        problem = topics.suffix_problem(topic)
        if problem is not None:
            return f"topic {topic!r}: {problem}"
    if not 1.0 <= config.relay_hz <= 500.0:
        return "relay_hz must be within 1..500"
    if not 0.0 <= config.q_min_rad < config.q_max_rad <= 2.0 * math.pi:
        return "need 0 <= q_min_rad < q_max_rad <= 2*pi"
    gains = (config.tau_max, config.kp_max, config.kd_max)
    if min(gains) < 0:
        return "tau_max, kp_max and kd_max must not be negative"
    if not (
        0 <= config.tau <= config.tau_max
        and 0 <= config.kp <= config.kp_max
        and 0 <= config.kd <= config.kd_max
    ):
        return "the default tau, kp and kd must be within their limits"
    if not 0 < config.release_error_rad < config.grip_error_rad:
        return "need 0 < release_error_rad < grip_error_rad"
    if min(config.grip_speed_rad_s, config.grip_confirm_s, config.release_s) <= 0:
        return "grip_speed_rad_s, grip_confirm_s and release_s must be positive"
    if not config.max_speed_rad_s > 0:
        return "max_speed_rad_s must be positive"
    if not 10.0 <= config.sim_rate_hz <= 2000.0 or config.sim_speed_rad_s <= 0:
        return "sim_rate_hz must be within 10..2000 and sim_speed_rad_s positive"
    if not 0 < config.link_stale_s <= 10:
        return "link_stale_s must be within 0..10"
    return None
