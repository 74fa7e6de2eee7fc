"""``fleet foxglove`` and a client offering the protocol's first name, ``foxglove.websocket.v1``
(older Foxglove apps, Lichtblick, Foxglove's ws-protocol clients). Before: the SDK's server behind
the gate answered HTTP 400 to that name, the gate's client thread failed on it and
``fleet foxglove`` exited 1 for every client. Now the client is served (the protocol is the same
under both names) and the command keeps serving the next one."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.scene3d.frames3d import urdf_topic
from fleet.web.access import FOXGLOVE_TOKEN_ENV as TOKEN_ENV
from testkit.foxglove_client import OLD_SUBPROTOCOL, SUBPROTOCOL, FoxgloveClient
from testkit.harness import FleetHarness, free_port, wait_until

TOKEN = "test-token-0123456789abcdef"


def test_both_names_of_the_protocol_are_served_and_the_command_keeps_running(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    with FleetHarness(tmp_path, arms=1) as harness:
        harness.start_router()
        port = free_port()
        process = harness.start(
            "foxglove", ["-m", "fleet.cli.main", "foxglove", "--port", str(port)]
        )
        url = f"ws://127.0.0.1:{port}/?token={TOKEN}"
        # Its printed URL says it serves (a probe of the port would be a client of its own).
        wait_until(lambda: url in harness.log("foxglove") or process.poll() is not None, 20.0)
        for subprotocol in (OLD_SUBPROTOCOL, SUBPROTOCOL, OLD_SUBPROTOCOL):
            assert process.poll() is None, harness.log("foxglove")
            fox = FoxgloveClient(url, subprotocol=subprotocol)
            try:
                fox.wait_for_topics({urdf_topic("a1")}, 15.0)
                assert fox.server_info is not None, subprotocol
            finally:
                fox.close()
        assert process.poll() is None, harness.log("foxglove")
        assert "Traceback" not in harness.log("foxglove"), harness.log("foxglove")
