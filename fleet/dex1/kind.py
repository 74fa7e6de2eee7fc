"""The Dex1-1 gripper as a device kind (``fleet/devices``): key word ``gripper``, inventory
table ``[grippers.<id>]``."""

from __future__ import annotations

from fleet.devices.kind import DeviceKind
from fleet.dex1.config import GripperConfig, check_gripper
from fleet.dex1.messages import GripperState
from fleet.wire import keys
from fleet.wire.payloads import device_payloads


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
    key=keys.GRIPPER,
    section="grippers",
    config=GripperConfig,
    check=check_gripper,
    payloads=device_payloads(keys.GRIPPER),
    summary=summary,
    agent="fleet.dex1.relay:GripperDriver",
    sim="fleet.dex1.sim:SimGripper",
)
