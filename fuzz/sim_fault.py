"""Fuzz target: the simulator's fault decoder (``fleet/sim/faults.py`` ``FAULT``) and what the
simulator does with a decoded fault (``apply_fault``).

Property: any input gives a ``Fault`` or ``PayloadError``; applying a decoded fault to a fresh
simulated arm succeeds or raises ``ValueError`` (the simulator answers those with an error reply
and catches nothing else); and an arm that accepted the fault keeps reporting: after a second of
motion into it, every report it would publish still encodes (the simulator's feedback thread
dies on a non-finite angle).
"""

from __future__ import annotations

from fuzz.common import instrumented, main

with instrumented():
    from fleet.d1 import protocol as p
    from fleet.sim.faults import FAULT, apply_fault
    from fleet.sim.model import SimArmModel
    from fleet.wire.payloads import PayloadError

TARGETS = (
    [60.0, -60.0, 60.0, 90.0, -60.0, 90.0, 65.0],
    [-60.0, 60.0, -60.0, -90.0, 60.0, -90.0, 0.0],
)
"""Two poses the arm is sent to after the fault, so it pushes into an obstacle from both sides."""


def check(data: bytes) -> None:
    """The property, for one input."""
    try:
        fault = FAULT.decode(data)
    except PayloadError:
        return
    model = SimArmModel()
    try:
        apply_fault(model.faults, fault)
    except ValueError:
        return
    for step, target in enumerate(TARGETS, start=1):
        model.target_deg = list(target)
        model.advance(0.5 * step)
        reports = [model.joint_report(), *model.status_reports()]
        for report in reports:
            if report is not None:
                p.encode_message(report)  # InvalidCommand here: a non-finite angle


def seeds() -> list[bytes]:
    """Every fault of docs/reference/keyspace.md, as the tests send them."""
    return [
        b'{"op":"stall","joint":1,"angle_deg":-20.5}',
        b'{"op":"unstall","joint":1}',
        b'{"op":"motor_offline","joint":3,"offline":true}',
        b'{"op":"error_status","error":true}',
        b'{"op":"drop_feedback","on":true}',
        b'{"op":"mute_acks","on":false}',
        b'{"op":"drag","joint":0,"angle_deg":40,"speed_deg_s":60}',
        b'{"op":"obstacle","joint":2,"angle_deg":30,"compliance":0.2,"hunting_deg":0.5,'
        b'"hunting_hz":3,"to_deg":10,"speed_deg_s":5,"error_after_s":0.4}',
        b'{"op":"remove_obstacle","joint":2}',
        b'{"op":"grip_object","width_deg":20,"compliance":0.05}',
        b'{"op":"noise","noise_deg":0.1,"jitter_s":0.03}',
        b'{"op":"clear"}',
    ]


if __name__ == "__main__":
    main(check)
