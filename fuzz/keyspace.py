"""Fuzz target: every key-space decoder (``fleet/wire/payloads.py``: the ``CHANNELS`` table and
``unknown_op``), each fed the same input.

Property: each kind gives its Struct or ``PayloadError``, never another exception; a decoded
payload re-encodes, and that decodes to an equal value (the coordinator re-publishes what it
decoded: a stop in its heartbeat); ``unknown_op`` returns None or an op no agent serves, at
most 64 characters, and never raises.
"""

from __future__ import annotations

from fuzz.common import instrumented, main

with instrumented():
    import msgspec

    from fleet.wire import keys, payloads
    from fleet.wire import messages as m

KINDS = tuple(c.payload for c in payloads.CHANNELS.values() if c.kind != keys.RAW_COMMAND)
"""Every Struct kind (a raw command is a plain JSON object, re-encoded by no one)."""


def check(data: bytes) -> None:
    """The property, for one input."""
    for kind in KINDS:
        try:
            value = kind.decode(data)
        except payloads.PayloadError:
            continue
        encoded = m.encode(value)
        again = msgspec.json.decode(encoded, type=kind.struct)
        assert again == value, (kind.name, value, again)
    op = payloads.unknown_op(data)
    assert op is None or (isinstance(op, str) and len(op) <= 64 and op not in m.COMMAND_OPS), op


def seeds() -> list[bytes]:
    """One valid payload of every public kind (as the fleet's processes write them), the
    hostile suite's poisons, and an unknown op."""
    from testkit.hostile import POISONS

    stop = m.StopRequest(stamp_ns=1, source="cli@host", stop_id="s1", reason="test")
    reply = m.CommandReply(
        ok=False,
        arm="a1",
        seq=4,
        received=True,
        executed=None,
        reached=None,
        latency_ms=1.5,
        error=m.ErrorInfo(int(m.ErrorCode.BUSY), "busy"),
        written_ns=2,
    )
    commands: list[m.ArmCommand] = [
        m.MoveJoint(joint=5, angle_deg=60.0, wait_reached=True, tolerance_deg=1.0),
        m.MoveJoints(angles_deg=[0.0, -60.0, 60.0, 0.0, 30.0, 0.0, 0.0], mode=0, lifetime_s=0.3),
        m.Torque(on=True, strength=80000),
        m.Power(on=False, owner="me", takeover=True),
        m.Zero(start_at_ns=5),
        m.Hold(),
        m.Release(owner="me"),
    ]
    values: list[msgspec.Struct] = [
        m.Joints(stamp_ns=1, angles_deg=[0.0] * 7, seq=3),
        m.ArmStatus(stamp_ns=1, link="ok", enabled=True, motors_ok=[True] * 7, estopped=True),
        m.Diag(1, "stale", 1, 2, 3, 4, 5, 6, 7, 9.5, 0.1, "x"),
        *commands,
        reply,
        stop,
        m.ResetRequest(stamp_ns=1, source="viewer"),
        m.StopAck("a1", "s1", "hold", 1, 2, 3, None),
        m.ResetAck("a1", "r1", "released", "released the stop by op", 1),
        m.Heartbeat(stamp_ns=1, coordinator="c", seq=1, period_s=0.1, stops={"*": stop}),
        m.FleetState(1, "c", {"a1": m.ArmSummary(True, "ok", contact=False)}),
        m.MultiArmRequest(target="all", command=commands[1], lead_s=0.3, phase="lift"),
        m.MultiArmReply(True, {"a1": reply}, 0.5),
        m.CoordinatorDiag(1, "c", 1, 2, 3, 4, 5, 6),
        m.StopReport("s1", "cli", 1, {"a1": m.StopTiming(1.0, 1.5, None)}),
        m.ChoreoStatus(1, "player@host:1:ab", "demo", "aborted", "a1 is stopped", 2, "ripple"),
        m.ContactEvent(1, 6, "confirmed", "model", 4.5, 0.75, grip=True),
    ]
    values += device_payloads()
    return [m.encode(v) for v in values] + list(POISONS.values())[:-1] + [b'{"op":"dance"}']


def device_payloads() -> list[msgspec.Struct]:
    """One valid payload of every device row of the channel table (the devices' payloads and
    commands, which the seeds had once left out)."""
    from fleet.dex1 import messages as dex1
    from fleet.g1 import messages as g1

    gripper = dex1.GripperState(
        stamp_ns=1, q_rad=1.0, opening_pct=15.9, dq_rad_s=0.0, tau_est=0.1,
        temperature_c=30.0, error=0, lost=0, link="ok", target_rad=None, gripping=False,
        estopped=False, stop_reason=None, dds_samples=3, relayed=2, bad_samples=0,
        dds_rate_hz=500.0, family="go", mount="a1",
    )  # fmt: skip
    robot = g1.G1State(
        stamp_ns=1, fsm_id=500, fsm_name="walk", fsm_mode=0, mode="static", task_id=0,
        task_time=0.0, link="ok", estopped=False, stop_reason=None, stop_action="stop_move",
        dds_samples=1, bad_samples=0, dds_rate_hz=100.0, service="sport",
        service_setting="auto", service_answered=True,
    )  # fmt: skip
    return [
        gripper,
        robot,
        dex1.GripperMove(open_pct=40.0),
        dex1.GripperHold(),
        dex1.GripEvent(1, "gl", "grip", 0.5, 0.2, 0.3, 0.8),
        g1.Damp(),
        g1.StopMove(),
        g1.SetVelocity(vx=0.1, duration_s=2.0),
        g1.GetFsmId(),
        g1.G1LowState(1, [0.0] * 29, [0.0] * 3, [1.0, 0.0, 0.0, 0.0], 7, 0),
        m.DeviceReply(True, "h1", None, 5, "500"),
        m.ProcessInfo("agent", "agent-lo", "host", 7, "1.0", 1, 2, ["a1"], 9100),
    ]


if __name__ == "__main__":
    main(check)
