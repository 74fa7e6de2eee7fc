"""Payload samples that tests of several folders decode, encode and publish."""

from __future__ import annotations

from fleet.dex1.messages import GripperState
from fleet.g1.messages import G1State

GRIP_STATE = GripperState(
    stamp_ns=1,
    q_rad=1.0,
    opening_pct=15.9,
    dq_rad_s=0.0,
    tau_est=0.1,
    temperature_c=30.0,
    error=0,
    lost=0,
    link="ok",
    target_rad=None,
    gripping=False,
    estopped=False,
    stop_reason=None,
    dds_samples=3,
    relayed=2,
    bad_samples=0,
    dds_rate_hz=500.0,
    family="go",
    mount="a1",
)
"""A Dex1-1 state with every field set (gripper ``gl`` on arm ``a1``)."""


def g1_state(service: str | None, setting: str, answered: bool) -> G1State:
    """A G1 state standing in the walking controller, with the service name as given."""
    return G1State(
        stamp_ns=1,
        fsm_id=500,
        fsm_name="walk",
        fsm_mode=0,
        mode="static",
        task_id=0,
        task_time=0.0,
        link="ok",
        estopped=False,
        stop_reason=None,
        stop_action="stop_move",
        dds_samples=1,
        bad_samples=0,
        dds_rate_hz=100.0,
        service=service,
        service_setting=setting,
        service_answered=answered,
    )
