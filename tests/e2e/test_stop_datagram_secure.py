"""The stops' datagram path in a secure fleet: QUIC datagrams (``quic/...?rel=0``) beside the TLS
endpoints, authenticated like the TLS session and under the same access control. Real router,
simulated arm and agent; mutual TLS and passwords."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import zenoh

from fleet.client import FleetClient
from fleet.security.session import credentials
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.info import query_info
from fleet.wire.session import RouterUnreachable, open_datagram
from fleet.wire.stoppath import DATAGRAM_QOS, JSON
from testkit.collect import Collector
from testkit.harness import FleetHarness, wait_until


def _seen(session: zenoh.Session, key: str) -> Collector[bytes]:
    """Payloads on ``key``, seen by a reliable (TLS) session."""
    return Collector(session, key, bytes)


def _count(seen: Collector[bytes], marker: bytes) -> int:
    return sum(marker in item for item in seen.items)


@pytest.fixture(params=["mtls", "password"])
def secure(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[FleetHarness]:
    with FleetHarness(tmp_path_factory.mktemp("dgsec"), arms=1, security=request.param) as h:
        h.start_router()
        h.start_sim()
        h.start_agent()
        yield h


def _agent_datagram(client: FleetClient) -> str | None:
    replies, _bad = query_info(client.session, client.inventory.fleet)
    agents = [r.info for r in replies if r.info.role == "agent"]
    return agents[0].datagram if agents else None


def test_a_secure_fleet_has_an_authenticated_datagram_path(secure: FleetHarness) -> None:
    h = secure
    operator = h.client()
    wait_until(lambda: h.all_links_ok(operator), 30.0)

    # Both ends opened their datagram session over QUIC (never plain UDP with TLS endpoints).
    wait_until(lambda: operator.datagram.path() is not None, 15.0)
    assert (operator.datagram.path() or "").startswith("quic/")
    wait_until(lambda: _agent_datagram(operator) is not None, 15.0)
    assert "quic/" in (_agent_datagram(operator) or "") and "rel=0" in (
        _agent_datagram(operator) or ""
    )

    # A stop put on the operator's QUIC datagram session only is acted on and acknowledged.
    acks = _seen(operator.session, operator.keys.arm("a1", keys.ESTOP_ACK))
    request = operator.stop_request(reason="over quic", source="test")
    datagram = operator.datagram.session
    assert datagram is not None

    def acked() -> bool:
        datagram.put(operator.keys.estop, m.encode(request), encoding=JSON, **DATAGRAM_QOS)  # type: ignore[arg-type]
        return _count(acks, request.stop_id.encode()) > 0

    wait_until(acked, 10.0, interval_s=0.2)
    operator.reset("a1")

    # The access control holds on the QUIC link: a viewer may not publish an agent's joints.
    viewer = h.inventory.with_principal("viewer")
    rogue = open_datagram(viewer.endpoints, viewer.datagram, 5.0, credentials(viewer, "viewer"))
    assert rogue is not None
    joints_key = operator.keys.arm("a1", keys.JOINTS)
    seen = _seen(operator.session, joints_key)
    try:
        for _ in range(20):
            rogue.put(joints_key, b'{"forged": "viewer"}', **DATAGRAM_QOS)  # type: ignore[arg-type]
            rogue.put(operator.keys.estop, m.encode(operator.stop_request(reason="marker")))
        # The viewer's own stops (anyone may stop) pass on the same link: the router has heard
        # its puts, and dropped the forged joints.
        wait_until(lambda: _latched(operator), 10.0)
        assert _count(seen, b"forged") == 0
    finally:
        rogue.close()  # type: ignore[no-untyped-call]
        operator.reset("a1")

    # Without credentials the QUIC endpoint does not open.
    with pytest.raises(RouterUnreachable):
        _open_bare(h)


def _latched(client: FleetClient) -> bool:
    status, _joints = client.snapshot(["a1"], wait_s=1.0)["a1"]
    return status is not None and bool(status.estopped)


def _open_bare(h: FleetHarness) -> None:
    session = open_datagram(h.inventory.endpoints, h.inventory.datagram, 3.0)
    if session is None:
        raise RouterUnreachable("no datagram session")
    session.close()  # type: ignore[no-untyped-call]
