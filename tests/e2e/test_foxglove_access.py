"""The Foxglove server behind the viewer's protections (issue 28, items 3 and 6): a per-run token,
an Origin allow-list, a private port a browser cannot open, an observer under ``[security]``, and
a channel table that made-up names cannot fill."""

from __future__ import annotations

import time
from pathlib import Path

import msgspec
import pytest
from websockets.exceptions import InvalidHandshake, InvalidStatus
from websockets.sync.client import connect

from fleet.scene3d.foxglove_bridge import (
    MAX_KEY_CHANNELS,
    BridgeRefused,
    FoxgloveBridge,
    check_observer,
)
from fleet.scene3d.frames3d import urdf_topic
from fleet.security_config import Security
from fleet.tables import PinnedTable
from fleet.wire import messages as m
from fleet.wire.stoppath import RELIABLE_QOS
from testkit.foxglove_client import SUBPROTOCOL, FoxgloveClient
from testkit.harness import FleetHarness, free_port, wait_until

TOKEN = "test-token-0123456789abcdef"
EVIL = "http://evil.example"


def _stop(source: str = "test") -> bytes:
    request = m.StopRequest(stamp_ns=time.time_ns(), source=source, stop_id=f"s{time.time_ns()}")
    return msgspec.json.encode(request)


def _refused(url: str, origin: str | None) -> int:
    with pytest.raises(InvalidStatus) as caught:
        FoxgloveClient(url, timeout_s=5.0, origin=origin)
    return caught.value.response.status_code


def test_token_origin_and_private_port(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=1) as harness:
        harness.start_router()
        inventory = harness.inventory.with_principal("viewer")
        with FoxgloveBridge(inventory, port=free_port(), token=TOKEN) as bridge:
            base = f"ws://127.0.0.1:{bridge.port}/"
            assert bridge.url == f"{base}?token={TOKEN}"
            # What the hostile review did: a page of another site, and no token at all.
            assert _refused(bridge.url, EVIL) == 403
            assert _refused(base, f"http://127.0.0.1:{bridge.port}") == 403
            assert _refused(f"{base}?token=wrong-token-0123456789", None) == 403
            assert bridge.gate.refusals["websocket"] == 3
            # The private server: plain WebSocket fails (TLS only, with a certificate no browser
            # trusts).
            with pytest.raises((InvalidHandshake, OSError, EOFError)):
                connect(f"ws://127.0.0.1:{bridge.server.port}/", open_timeout=3.0)
            # Foxglove's web app with the token, and a client without an Origin (desktop, script).
            for origin in ("https://app.foxglove.dev", None):
                fox = FoxgloveClient(bridge.url, origin=origin)
                try:
                    assert fox.ws.subprotocol == SUBPROTOCOL
                    fox.wait_for_topics({urdf_topic("a1")}, 10.0)
                finally:
                    fox.close()
            assert bridge.gate.admitted == 2


def test_secure_mode_serves_as_an_observer(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=1) as harness:
        secure = msgspec.structs.replace(harness.inventory, security=Security(mode="mtls"))
        with pytest.raises(BridgeRefused, match="'operator' has role 'operator'"):
            check_observer(secure.with_principal("operator"))
        check_observer(secure.with_principal("viewer"))
        check_observer(harness.inventory.with_principal("operator"))  # open mode: as before


def test_made_up_names_never_hide_an_inventory_arms_channel(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=3) as harness:
        harness.start_router()
        client = harness.client()
        inventory = harness.inventory.with_principal("viewer")
        with FoxgloveBridge(inventory, port=free_port(), token=TOKEN) as bridge:
            fox = FoxgloveClient(bridge.url)
            try:
                fox.wait_for_topics({urdf_topic("a3")}, 10.0)
                # The review's attack: 1100 stops for made-up arms, then the real a3's stop. BLOCK,
                # as a stop is put: a plain put is DROP, and Zenoh dropped some of a burst this
                # long on a loaded host (the eviction count then fell short).
                for i in range(MAX_KEY_CHANNELS + 100):
                    client.session.put(f"fleet/test/arm/made{i}/estop", _stop(), **RELIABLE_QOS)
                wait_until(lambda: bridge._channels.evicted >= 100, 20.0)
                real = "fleet/test/arm/a3/estop"
                client.session.put(real, _stop(), **RELIABLE_QOS)
                fox.wait_for_topics({real}, 10.0)
                assert len(bridge._channels) <= MAX_KEY_CHANNELS + bridge._channels.pinned_count()
                # The real arm's channel stays through another flood.
                for i in range(MAX_KEY_CHANNELS + 100):
                    client.session.put(f"fleet/test/arm/more{i}/estop", _stop(), **RELIABLE_QOS)
                wait_until(lambda: bridge._channels.evicted >= 1200, 20.0)
                assert real in bridge._channels
                assert real in fox.topics() or fox.wait_for_topics({real}, 5.0)
            finally:
                fox.close()


def test_pinned_table_evicts_only_made_up_keys() -> None:
    evicted: list[str] = []
    table: PinnedTable[str, str] = PinnedTable(
        3, lambda key: key.startswith("real"), lambda key, _v: evicted.append(key)
    )
    for key in ("real1", "x1", "x2", "x3", "real2", "x4"):
        assert table.get(key, str.upper) == key.upper()
    assert evicted == ["x1"] and "real1" in table and "real2" in table
    table.get("x2", str.upper)  # used: now the most recent
    table.get("x5", str.upper)
    assert evicted == ["x1", "x3"] and len(table) == 5 and table.pinned_count() == 2
