"""The demo's story in a real headless Chromium: a dance plays (``fleet play``, its own
process) and the page says so; a stop ends it, and the page shows the dance STOPPED in red
with the reason, and logs it. Before, the page showed arms standing still and nothing else."""

from __future__ import annotations

import re

from testkit.browser import Browser
from testkit.harness import FleetHarness, free_port, wait_until
from viewer.app import Viewer

SCRIPT = """
[choreo]
name = "browser dance"

[[step]]
label = "out"
duration_s = 1.5
all = [30, -30, 40, 0, 30, 20, 20]

[[step]]
label = "back"
duration_s = 1.5
all = [-30, -30, 40, 0, 30, -20, 40]
"""


def _dance_line(browser: Browser) -> tuple[str, str]:
    """(state, text) of the newest dance's status line ("", "" before any)."""
    line = browser.page.locator("#dance-status [data-dance-state]").first
    if not line.count():
        return "", ""
    return line.get_attribute("data-dance-state") or "", line.inner_text()


def test_the_page_shows_the_dance_playing_then_stopped_and_why(
    fleet_harness: FleetHarness, browser: Browser
) -> None:
    h = fleet_harness
    client = h.start_fleet()
    path = h.tmp_path / "dance.toml"
    path.write_text(SCRIPT)
    with Viewer(h.inventory.with_principal("operator"), port=free_port()) as viewer:
        browser.page.goto(viewer.url)
        browser.page.get_by_role("button", name="Fit view").wait_for(timeout=30_000)
        argv = ["-m", "fleet.cli.main", "play", str(path), "--loops", "0", "--ready-s", "10"]
        player = h.start("player", argv)
        wait_until(lambda: _dance_line(browser)[0] == "playing", 30.0)
        playing = r"Dance 'browser dance': playing \(pass \d+, step '(out|back)'\)"
        assert re.search(playing, _dance_line(browser)[1]), _dance_line(browser)
        client.estop("a1", reason="browser test")
        wait_until(lambda: _dance_line(browser)[0] == "aborted", 15.0)
        state, text = _dance_line(browser)
        assert "Dance 'browser dance' STOPPED at" in text and "'a1' is stopped" in text, text
        rows = browser.page.locator("#event-log tr[data-kind='dance stopped']")
        wait_until(lambda: rows.count() == 1, 5.0)
        assert "'a1' is stopped" in rows.first.inner_text()
        browser.save_page("dance-stopped")
        wait_until(lambda: player.poll() is not None, 15.0)
