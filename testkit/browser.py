"""A real headless Chromium for the viewer's tests (Debian's, driven by playwright; no browser
downloads): one page in a fresh profile per test, with its requests and WebSocket frames counted.
The ``browser`` fixture is in tests/conftest.py.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import Page, sync_playwright

from testkit.harness import wait_until

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts" / "viewer"


class Browser:
    """One page in a fresh Chromium profile; counts the viewer's websocket frames."""

    def __init__(self, page: Page) -> None:
        self.page = page
        self.frames = 0
        self.bytes = 0
        self.requests: list[str] = []
        """Every URL the page asked for (HTTP requests and WebSockets)."""
        page.on("websocket", self._on_websocket)
        page.on("request", lambda request: self.requests.append(request.url))

    def _on_websocket(self, socket: Any) -> None:
        def on_frame(payload: str | bytes) -> None:
            self.frames += 1
            self.bytes += len(payload)

        self.requests.append(socket.url)
        socket.on("framereceived", on_frame)

    def elsewhere(self, origin: str) -> list[str]:
        """URLs the page asked for outside ``origin`` (inline data excepted)."""
        ws_origin = origin.replace("http://", "ws://", 1)
        own = (origin + "/", ws_origin + "/", "data:", "blob:")
        return [url for url in self.requests if not url.startswith(own)]

    def canvas(self, name: str) -> np.ndarray:
        """A screenshot of the 3D canvas (kept as an artefact) as an RGB array."""
        png = self.page.locator("canvas").first.screenshot()
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        (ARTIFACTS / f"{name}.png").write_bytes(png)
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)

    def save_page(self, name: str) -> None:
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        self.page.screenshot(path=str(ARTIFACTS / f"{name}.png"))

    def arm_online(self, arm: str) -> str | None:
        row = self.page.locator(f"tr[data-arm='{arm}']")
        return row.get_attribute("data-online") if row.count() else None


def open_browser(tmp_path: Path) -> Iterator[Browser]:
    """The ``browser`` fixture's body."""
    if not CHROMIUM.exists():
        pytest.fail("no /usr/bin/chromium: run scripts/ensure-chromium (make test does)")
    with sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            str(tmp_path / "chromium-profile"),  # a fresh user-data dir per test
            executable_path=str(CHROMIUM),
            headless=True,
            args=CHROMIUM_ARGS,
            viewport={"width": 1280, "height": 800},
        )
        try:
            yield Browser(context.new_page())
        finally:
            context.close()


def click_until(
    click: Callable[[], None], done: Callable[[], object], timeout_s: float, again_s: float = 3.0
) -> None:
    """``click`` (an idempotent control: a safe-mode button, a stop), then wait for ``done``;
    click again each ``again_s`` it is not (a click on a loaded host, while the page was
    still laying out a folder just opened, was seen never to reach the viewer; one "Stop
    move" waited 10 s for nothing). AssertionError after ``timeout_s``."""
    clicked = [time.monotonic()]
    click()

    def clicked_and_done() -> object:
        result = done()
        if not result and time.monotonic() - clicked[0] > again_s:
            click()
            clicked[0] = time.monotonic()
        return result

    wait_until(clicked_and_done, timeout_s, interval_s=0.1)
