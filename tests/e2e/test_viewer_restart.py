"""``fleet viewer`` restarted for the same fleet keeps its token: a tab opened on the first
run's URL still enters the second (it got 403), the token file is its owner's only, and the
viewer's output shows the token in its URL line only."""

from __future__ import annotations

import http.client
import stat
from urllib.parse import urlsplit

from testkit.harness import FleetHarness, free_port, wait_until


def _start_viewer(harness: FleetHarness, port: int, *options: str) -> str:
    """``fleet viewer`` as its own process; the URL it printed."""
    harness.start("viewer", ["-m", "fleet.cli.main", "viewer", "--port", str(port), *options])

    def printed() -> str | None:
        for line in harness.log("viewer").splitlines():
            if "d1-fleet viewer: http" in line:
                return line.split("d1-fleet viewer: ", 1)[1].split()[0]
        assert harness.processes["viewer"].poll() is None, harness.log("viewer")
        return None

    return wait_until(printed, 30.0)


def _status(url: str) -> int:
    """The status of a page load of ``url`` (303 enters, 403 refused)."""
    parts = urlsplit(url)
    connection = http.client.HTTPConnection(parts.hostname or "", parts.port, timeout=10)
    try:
        connection.request("GET", f"{parts.path}?{parts.query}")
        return connection.getresponse().status
    finally:
        connection.close()


def test_a_restarted_viewer_keeps_its_token(fleet_harness: FleetHarness) -> None:
    h = fleet_harness
    h.start_router()
    port = free_port()
    first = _start_viewer(h, port)
    assert _status(first) == 303
    h.stop("viewer")
    second = _start_viewer(h, port)
    assert second == first
    assert _status(first) == 303  # the tab opened before the restart enters
    token = urlsplit(first).query.removeprefix("token=")
    path = h.tmp_path / "state" / h.inventory.fleet / "viewer.token"
    assert path.read_text().strip() == token
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    for name in ("viewer", "viewer.log.1"):
        text = h.log("viewer") if name == "viewer" else (h.tmp_path / name).read_text()
        assert [
            ln for ln in text.splitlines() if token in ln and "d1-fleet viewer:" not in ln
        ] == []
    # A new token on demand: the old URL is refused from then on.
    h.stop("viewer")
    third = _start_viewer(h, port, "--new-token")
    assert third != first and _status(first) == 403 and _status(third) == 303
