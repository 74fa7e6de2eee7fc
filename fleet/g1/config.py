"""A G1's inventory entry: ``[g1.<id>]``."""

from __future__ import annotations

import math
from typing import Literal

from fleet.devices.base import DeviceBase
from fleet.g1.arms import (
    COUNT,
    DEFAULT_KD,
    DEFAULT_KP,
    MAX_RELEASE_S,
    MIN_RELEASE_S,
    ArmLimits,
)

G1StopAction = Literal["stop_move", "damp"]
G1Service = Literal["sport", "loco", "auto"]


class G1Config(DeviceBase, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """One G1 (its high-level motion service)."""

    service: G1Service = "sport"
    """The LocoClient service's name: ``sport`` (ai_sport >= 8.2, Unitree's SDK today), ``loco``
    (ai_sport < 8.2), ``auto`` (ask GetFsmId on both at start, use the one that answered)."""
    stop_action: G1StopAction = "stop_move"
    """``stop_move``: zero velocity and continuous gait off, the robot keeps balancing
    (confirmed by fsm_mode 0); ``damp``: the always-allowed fallback (fsm 1), written even
    without state. A damped humanoid sinks to the ground."""
    relay_hz: float = 10.0
    """Zenoh state rate (newest wins; every change of fsm_id or fsm_mode is put at once)."""
    rpc_timeout_s: float = 1.0
    """How long a LocoClient call waits for the robot's answer (the SDK's default)."""
    max_vx: float = 0.5
    max_vy: float = 0.3
    max_omega: float = 0.5
    max_duration_s: float = 3.0
    """SetVelocity's duration is bounded (LocoClient's Move(continous) would send 864000 s)."""
    allow_continuous_move: bool = False
    """``move`` with ``continuous`` (Unitree's 864000 s velocity) is refused unless this is set."""
    arm_engage_s: float = 1.0
    """rt/arm_sdk: the weight's ramp 0 -> 1 when control starts from a weight known to be 0
    (>= 0.4 s: steps <= 0.05); from an unknown weight it starts at 1 on the measured pose."""
    arm_release_s: float = MIN_RELEASE_S
    """rt/arm_sdk: the weight's ramp 1 -> 0 on a release (3..5 s: never faster than Unitree's
    example; the agent's exit, which releases, must fit its 8 s shutdown bound)."""
    arm_on_stop: Literal["hold", "release"] = "hold"
    """What a stop, the watchdog and a lapsed lease do to the arms: ``hold`` (the weight kept,
    the commanded pose frozen, until an ``arm_release`` or a new target after a reset) or
    ``release`` (the weight ramped to 0 over ``arm_release_s``: the robot's own controller
    takes the arms back, which moves them to its own pose). The stop action (StopMove, damp)
    goes out at once either way. At the agent's exit (SIGTERM/SIGINT) the arms are released."""
    arm_speed_rad_s: float = 0.5
    """The commanded pose's default top speed towards an arm target (every joint)."""
    arm_max_speed_rad_s: float = 1.5
    """A target asking a higher ``speed_rad_s`` is refused (too fast)."""
    arm_max_jump_rad: float = 0.6
    """A target this far from the measured pose on any joint is refused."""
    arm_kp: list[float] | None = None
    """17 stiffnesses (motors 12-28); None: Unitree's example's 60."""
    arm_kd: list[float] | None = None
    """17 dampings; None: Unitree's example's 1.5."""
    link_stale_s: float = 0.5
    base_xyz: list[float] | None = None
    """Where the viewer draws it (m, the point under its pelvis on the floor); None: beside
    the arms (to their left, one metre apart)."""
    base_yaw_deg: float = 0.0
    """Which way the drawn G1 faces (0: along +x, as the arms' default)."""
    sim_rate_hz: float = 100.0
    """Simulator only: rt/sportmodestate rate (and rt/lowstate's, unless ``sim_lowstate_hz``)."""
    sim_lowstate_hz: float | None = None
    """Simulator only: rt/lowstate rate (None: ``sim_rate_hz``). Each sample is a 35-motor
    struct with Unitree's CRC, ~1 ms of Python to build and ~0.5 ms for the agent to take: a
    test bed of many processes on few cores runs it slower (the agent checks only that it is
    fresh within ``link_stale_s``)."""
    sim_fsm_id: int = 500
    """Simulator only: the FSM it starts in (500: walking controller, standing)."""
    sim_settle_s: float = 0.3
    """Simulator only: how long it keeps stepping (fsm_mode 1) after the velocity ends."""
    sim_service: Literal["sport", "loco"] = "sport"
    """Simulator only: the name it serves the LocoClient API on."""
    sim_state: bool = True
    """Simulator only: publish rt/sportmodestate (false: firmware before 1.5.1 has none)."""


def arm_limits(config: G1Config) -> ArmLimits:
    """The arm stream's settings from ``config`` (the lease is the hold time)."""
    return ArmLimits(
        engage_s=config.arm_engage_s,
        release_s=config.arm_release_s,
        on_stop=config.arm_on_stop,
        hold_s=config.lease_s,
        speed_rad_s=config.arm_speed_rad_s,
        max_speed_rad_s=config.arm_max_speed_rad_s,
        max_jump_rad=config.arm_max_jump_rad,
        kp=tuple(config.arm_kp or (DEFAULT_KP,) * COUNT),
        kd=tuple(config.arm_kd or (DEFAULT_KD,) * COUNT),
    )


def check_g1(config: G1Config) -> str | None:
    """Why ``config`` is unusable, or None."""
    if not 1.0 <= config.relay_hz <= 500.0:
        return "relay_hz must be within 1..500"
    if not 0 < config.rpc_timeout_s <= 30:
        return "rpc_timeout_s must be within 0..30"
    if min(config.max_vx, config.max_vy, config.max_omega) < 0:
        return "max_vx, max_vy and max_omega must not be negative"
    if not 0 < config.max_duration_s <= 60:
        return "max_duration_s must be within 0..60"
    if not 1.0 <= config.sim_rate_hz <= 1000.0 or config.sim_settle_s < 0:
        return "sim_rate_hz must be within 1..1000, sim_settle_s not negative"
    low_hz = config.sim_lowstate_hz
    if low_hz is not None and not (
        low_hz * config.link_stale_s > 1.0 and low_hz <= config.sim_rate_hz
    ):
        return "sim_lowstate_hz must be above 1 / link_stale_s and at most sim_rate_hz"
    if not 0.4 <= config.arm_engage_s <= 10:
        return "arm_engage_s must be within 0.4..10"
    if not MIN_RELEASE_S <= config.arm_release_s <= MAX_RELEASE_S:
        return (
            f"arm_release_s must be within {MIN_RELEASE_S:g}..{MAX_RELEASE_S:g} (never faster "
            "than Unitree's example's 3 s; the agent releases the arms within its shutdown)"
        )
    if not 0 < config.arm_speed_rad_s <= config.arm_max_speed_rad_s <= 3.0:
        return "need 0 < arm_speed_rad_s <= arm_max_speed_rad_s <= 3"
    if not 0 < config.arm_max_jump_rad <= 1.5:
        return "arm_max_jump_rad must be within 0..1.5"
    for name in ("arm_kp", "arm_kd"):
        gains = getattr(config, name)
        if gains is not None and (len(gains) != 17 or not all(0 <= g <= 500 for g in gains)):
            return f"{name} must be 17 values within 0..500 (motors 12-28)"
    placed = [*(config.base_xyz or []), config.base_yaw_deg]
    if config.base_xyz is not None and len(config.base_xyz) != 3:
        return "base_xyz must be 3 values (x, y, z in metres)"
    if not all(math.isfinite(v) and abs(v) <= 1000 for v in placed):
        return "base_xyz and base_yaw_deg must be finite (within 1000)"
    if not 0 < config.link_stale_s <= 10:
        return "link_stale_s must be within 0..10"
    return None
