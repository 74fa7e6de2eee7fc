"""The G1 humanoid's high-level service as a device kind: key word ``g1``, inventory table
``[g1.<id>]``."""

from __future__ import annotations

from fleet.devices.kind import DeviceKind
from fleet.g1.config import G1Config, check_g1
from fleet.g1.messages import G1State
from fleet.wire import keys
from fleet.wire.payloads import device_payloads


def summary(state: G1State) -> str:
    """One ``fleet status`` line's details."""
    stopped = f" STOPPED ({state.stop_action})" if state.estopped else ""
    if state.estopped and state.stop_detail:
        stopped += f" {state.stop_detail}"
    service = state.service or f"{state.service_setting}: asking sport, loco"
    if state.service is not None and not state.service_answered:
        service += " (no answer to GetFsmId)"
    elif state.service_setting == "auto" and state.service is not None:
        service += " (auto)"
    return (
        f"fsm {state.fsm_id} {state.fsm_name}, {state.mode}, {state.dds_rate_hz:.0f} Hz, "
        f"service {service}{stopped}"
    )


KIND = DeviceKind(
    key=keys.G1,
    section="g1",
    config=G1Config,
    check=check_g1,
    payloads=device_payloads(keys.G1),
    summary=summary,
    agent="fleet.g1.relay:G1Driver",
    sim="fleet.g1.sim:SimG1",
    stop_actions=("stop_move", "damp"),
)
