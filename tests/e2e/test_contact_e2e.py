"""Contact detection end to end on real processes: the simulated arm pushes into an obstacle
(injected on ``arm/<arm>/sim/fault``), the agent's detector publishes a contact event on the
key space, and the coordinator's policy stops the arm (a snag while lifting)."""

from __future__ import annotations

import time

import msgspec
import zenoh

from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import encode
from testkit.harness import FleetHarness, wait_until


def _query(session: zenoh.Session, key: str, payload: bytes) -> bytes:
    for reply in session.get(key, payload=payload, timeout=5.0):
        if reply.ok is not None:
            return bytes(reply.ok.payload.to_bytes())
    raise AssertionError(f"no reply on {key}")


def test_obstacle_contact_reaches_key_space_and_coordinator_stops_arm(
    fleet_harness: FleetHarness,
) -> None:
    h = fleet_harness
    started = time.monotonic()
    h.start_router()
    h.start_sim()
    h.start_agent()
    h.start_coordinator()
    client = h.client()
    wait_until(lambda: h.all_links_ok(client), 30.0)
    events: list[m.ContactEvent] = []
    sub = client.session.declare_subscriber(
        client.keys.arm("a1", keys.CONTACT),
        lambda s: events.append(payloads.CONTACT.decode(s.payload.to_bytes())),
    )
    fault = b'{"op": "obstacle", "joint": 1, "angle_deg": 15.0, "compliance": 0.05}'
    assert b'"ok":true' in _query(client.session, client.keys.arm("a1", keys.SIM_FAULT), fault)
    request = m.MultiArmRequest(
        target="a1", command=m.MoveJoint(joint=1, angle_deg=45.0), phase="lift"
    )
    wait_until(
        lambda: _coordinator_up(client.session, client.keys.coordinator_command(client.principal)),
        10.0,
    )
    reply = msgspec.json.decode(
        _query(client.session, client.keys.coordinator_command(client.principal), encode(request)),
        type=m.MultiArmReply,
    )
    assert reply.ok, reply

    confirmed = wait_until(
        lambda: [e for e in events if e.state == "confirmed" and e.joint == 1], 5.0
    )[0]
    assert confirmed.commanded and confirmed.error_deg > 5.0
    assert confirmed.measured_deg is not None and 14.0 < confirmed.measured_deg < 18.0
    assert confirmed.method in ("model", "stall", "status", "oscillation")
    assert [e.state for e in events][:2] == ["suspected", "confirmed"]

    status = wait_until(
        lambda: (s := client.snapshot()["a1"][0]) is not None and s.estopped and s, 5.0
    )
    assert status.stop_reason is not None and "snag while lifting" in status.stop_reason
    sub.undeclare()
    assert time.monotonic() - started < 20.0


def _coordinator_up(session: zenoh.Session, key: str) -> bool:
    probe = m.MultiArmRequest(target="a1", command=m.Release(owner="probe"))
    return any(r.ok is not None for r in session.get(key, payload=encode(probe), timeout=1.0))
