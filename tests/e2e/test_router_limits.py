"""The router's payload limits cover every kind (issue 21): a 900 KiB query on a device command
key dies at the router (no agent ever answers it), while the device's normal traffic passes.

Real processes on loopback: a router with mutual TLS and the access control and payload limits
generated from the inventory, ``fleet sim`` (one arm, a Dex1-1, a G1), the arm's agent and one
devices agent. A query the router drops gets no reply at all; one that reaches the agent gets
its refusal (3204, over the decoder's 4 KiB), so "no reply, and the next command is answered"
can only mean the router dropped it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import msgspec
import pytest

from fleet.client import FleetClient
from fleet.dex1.messages import GripperMove
from fleet.g1.messages import StopMove
from fleet.wire import keys
from fleet.wire import messages as m
from testkit.harness import FleetHarness, wait_until

# Devices served by the arms' agent principal: one certificate for every agent process.
EXTRA = '[grippers.gl]\nmount = "a1"\nagent = "agent-lo"\n\n[g1.h1]\nagent = "agent-lo"\n'
HUGE = b'{"op":"move","open_pct":40,"x":"' + b"z" * (900 * 1024) + b'"}'


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[FleetHarness, FleetClient]]:
    """One arm, a gripper and a G1 behind a router with mTLS and access control."""
    with FleetHarness(tmp_path_factory.mktemp("limits"), extra=EXTRA, security="mtls") as h:
        h.start_router()
        h.start_sim()
        h.start_agent()
        h.start(
            "devices",
            ["-m", "edge_agent", "--principal", "agent-lo"] + ["--device", "gl", "--device", "h1"],
        )
        operator = h.client()
        up = lambda: all(s is not None for s in operator.device_snapshot(wait_s=1.0).values())  # noqa: E731
        try:
            wait_until(up, 40.0)
            wait_until(lambda: h.all_links_ok(operator), 30.0)
        except AssertionError:
            raise AssertionError(h.diagnose(operator) + h.log("devices")[-3000:]) from None
        yield h, operator


def _replies(client: FleetClient, key: str, payload: bytes) -> list[object]:
    return [r for r in client.session.get(key, payload=payload, timeout=3.0)]


@pytest.mark.parametrize(("kind", "device"), [("gripper", "gl"), ("g1", "h1")])
def test_a_huge_query_on_a_device_command_key_dies_at_the_router(
    secure: tuple[FleetHarness, FleetClient], kind: str, device: str
) -> None:
    h, operator = secure
    key = operator.keys.device_command(kind, device, operator.principal)
    assert key.endswith(f"/{kind}/{device}/cmd/operator")
    assert _replies(operator, key, HUGE) == [], "a 900 KiB command reached the agent"
    normal = GripperMove(open_pct=40.0) if kind == "gripper" else StopMove()
    reply = operator.device_command(device, normal)
    assert reply.ok, reply


def test_device_states_and_resets_pass_and_huge_resets_do_not(
    secure: tuple[FleetHarness, FleetClient],
) -> None:
    h, operator = secure
    viewer = h.client("viewer")
    snapshot = viewer.device_snapshot(wait_s=2.0)
    assert all(s is not None for s in snapshot.values()), snapshot
    seen: list[bytes] = []
    key = operator.keys.device("gripper", "gl", keys.RESET)
    sub = viewer.session.declare_subscriber(key, lambda s: seen.append(s.payload.to_bytes()))
    small = msgspec.json.encode(m.ResetRequest(stamp_ns=time.time_ns(), source="operator"))
    try:
        wait_until(lambda: operator.session.declare_publisher(key).matching_status.matching, 5.0)
        operator.session.put(key, b'{"x":"' + b"z" * 8000 + b'"}')
        operator.session.put(key, small)
        wait_until(lambda: small in seen, 5.0)
        assert seen == [small], "an 8 KB device reset crossed the router"
    finally:
        sub.undeclare()
