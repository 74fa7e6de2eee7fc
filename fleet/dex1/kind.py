"""The Dex1-1 gripper as a device kind (``fleet/devices``): key word ``gripper``, inventory
table ``[grippers.<id>]``."""

from __future__ import annotations

from fleet.devices import DeviceKind
from fleet.dex1.config import GripperConfig, check_gripper
from fleet.dex1.messages import GripEvent, GripperCommand, GripperState
from fleet.wire import keys
from fleet.wire.payloads import KIB, payload_kind


def summary(state: GripperState) -> str:
    """One ``fleet status`` line's details."""
    flags = " GRIP" if state.gripping else ""
    flags += " STOPPED" if state.estopped else ""
    mount = f" on {state.mount}" if state.mount else ""
    return (
        f"open {state.opening_pct:5.1f} % ({state.q_rad:.2f} rad) tau {state.tau_est:.2f} "
        f"{state.dds_rate_hz:.0f} Hz DDS{mount}{flags}"
    )


KIND = DeviceKind(
    key="gripper",
    section="grippers",
    config=GripperConfig,
    check=check_gripper,
    payloads={
        keys.STATE: payload_kind("gripper state", GripperState, 4 * KIB),
        keys.CMD: payload_kind("gripper command", GripperCommand, 4 * KIB),
        keys.CONTACT: payload_kind("gripper contact", GripEvent, 4 * KIB),
    },
    summary=summary,
    agent="fleet.dex1.relay:GripperDriver",
    sim="fleet.dex1.sim:SimGripper",
)
