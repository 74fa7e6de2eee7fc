"""A G1's inventory entry: ``[g1.<id>]``."""

from __future__ import annotations

from typing import Literal

from fleet.devices.base import DeviceBase

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
    link_stale_s: float = 0.5
    sim_rate_hz: float = 100.0
    """Simulator only: rt/sportmodestate rate."""
    sim_fsm_id: int = 500
    """Simulator only: the FSM it starts in (500: walking controller, standing)."""
    sim_settle_s: float = 0.3
    """Simulator only: how long it keeps stepping (fsm_mode 1) after the velocity ends."""
    sim_service: Literal["sport", "loco"] = "sport"
    """Simulator only: the name it serves the LocoClient API on."""
    sim_state: bool = True
    """Simulator only: publish rt/sportmodestate (false: firmware before 1.5.1 has none)."""


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
    if not 0 < config.link_stale_s <= 10:
        return "link_stale_s must be within 0..10"
    return None
