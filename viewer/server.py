"""viser's web server with the access guard (fleet/web/access.py) in front and its share tunnel off.

This is the one module that reaches into viser's internals; it was written against viser 1.1.1
and websockets 16.

**Why a shim.** viser 1.1.1 has no public hook for the opening handshake: ``ViserServer()``
starts its server at once, in ``viser.infra._infra``, by calling
``websockets.asyncio.server.serve(..., process_request=viser_http_server)`` with no
``origins``, and ``viser_http_server`` is a closure. ``process_request`` itself is websockets'
public extension point, so the shim swaps ``websockets.asyncio.server.serve`` for a wrapper
only while ``ViserServer()`` runs (its constructor returns after the server is bound, so the
wrapper has been called by then), under a lock, and restores it. The wrapper puts
``AccessGuard.process_request`` in front of viser's. If a later viser starts its server some
other way, the wrapper is never called and ``start_server`` refuses to run the viewer
(``AccessNotInstalled``): it fails closed, never open. tests/e2e/test_viewer_access.py checks the
version and the behaviour, so an upgrade of viser fails the suite loudly.

**Keys on a focused slider.** viser 1.1.1's client moves the camera with the arrow keys (and
W/A/S/D/Q/E) from a ``keydown`` listener on ``document`` that skips only INPUT, TEXTAREA,
SELECT and contentEditable targets (``CameraControls.tsx``, ``utils/isFormElement.ts``).
Mantine's slider thumb is a ``<div role="slider">``, so an arrow key that jogged an arm also
orbited the camera and the arm left the view. viser has no setting for this (no
Python option turns the keyboard camera off, and its camera lock is for gizmo drags) and runs no
script of ours, so the page it serves gets one small script (``PAGE_SCRIPT``): a ``keydown``
listener on ``<html>``, which the event reaches after the slider's own (React's, on the root
element) and before viser's on ``document``, stops the slider's keys there. Nothing in viser is
changed; the page is rewritten on its way out, like the guard's headers.

**Share tunnel.** viser's share button asks the server (``ShareUrlRequest``) to open a public
tunnel to share.viser.studio: anyone who can reach that URL could then use the viewer. The button
is hidden (``configure_theme(show_share_button=False)`` in panels.py) and, since any connected
client can send the message without the button, ``ViewerServer.request_share_url`` refuses:
the viewer process opens no outbound connection.
"""

from __future__ import annotations

import gzip
import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import rich
import viser
import websockets.asyncio.server
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from fleet.web.access import AccessGuard, ProcessRequest
from fleet.web.refusals import Refusals

log = logging.getLogger("viewer.server")

TESTED_VISER = "1.1.1"
"""The viser version this shim was checked against (tests/e2e/test_viewer_access.py asserts it)."""

_SWAP_LOCK = threading.Lock()
"""Serializes the swap of ``websockets.asyncio.server.serve`` (two viewers in one process)."""


class _HandshakeNoise(logging.Filter):
    """Drops websockets' line per refused or malformed handshake. A page can knock thousands of
    times a second; the guard counts its refusals and logs them rate-limited instead. (viser
    adds a filter like this one itself, but only once a request reaches it.)"""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not (
            message.startswith("connection rejected (") or message == "opening handshake failed"
        )


_HANDSHAKE_NOISE = _HandshakeNoise()


class AccessNotInstalled(RuntimeError):
    """viser started its server without going through the access guard."""


class ViewerServer(viser.ViserServer):
    """A ``ViserServer`` whose share tunnel can never be opened."""

    def __init__(self, host: str, port: int, label: str) -> None:
        # Before super().__init__: the server takes messages as soon as it is bound, inside it.
        self.share_refusals = Refusals(log)
        super().__init__(host=host, port=port, label=label, verbose=False)

    def request_share_url(self, verbose: bool = True) -> str | None:
        """Refuse: the viewer never opens a public tunnel (or any outbound connection)."""
        self.share_refusals.refuse("share", "a request for a public share URL (never opened)")
        return None

    def disconnect_share_url(self) -> None:
        """Nothing to disconnect: no tunnel is ever opened."""


SLIDER_KEYS = (
    "ArrowLeft",
    "ArrowRight",
    "ArrowUp",
    "ArrowDown",
    "Home",
    "End",
    "PageUp",
    "PageDown",
)
"""The keys Mantine's slider uses (viser's camera moves on the four arrows)."""

PAGE_SCRIPT = (
    "<script>/* d1-fleet: a key on a focused slider moves the slider only, never the camera"
    " (viewer/server.py) */"
    'document.documentElement.addEventListener("keydown",function(e){'
    "var t=e.target;"
    "if(t instanceof Element&&t.closest('[role=\"slider\"]')&&"
    f"{list(SLIDER_KEYS)!r}.indexOf(e.key)>=0)e.stopPropagation();}});</script>"
).encode()


def with_page_script(inner: ProcessRequest | None) -> ProcessRequest:
    """viser's ``process_request`` with ``PAGE_SCRIPT`` put into the HTML page it serves
    (gzipped or not; each rewritten page computed once)."""
    pages: dict[tuple[bytes, str], bytes] = {}  # viser's cached page (hash kept) -> ours

    def process_request(connection: ServerConnection, request: Request) -> Response | None:
        response = inner(connection, request) if inner is not None else None
        if response is None or response.status_code != 200:
            return response
        if not response.headers.get("Content-Type", "").startswith("text/html"):
            return response
        encoding = response.headers.get("Content-Encoding", "identity")
        key = (bytes(response.body), encoding)
        if key not in pages:
            page = gzip.decompress(key[0]) if encoding == "gzip" else key[0]
            at = page.rfind(b"</head>")  # the page's own, after viser's inline bundle
            if at < 0:
                log.warning("viser's page has no </head>: arrow keys on a slider move the camera")
            else:
                page = page[:at] + PAGE_SCRIPT + page[at:]
            pages[key] = gzip.compress(page) if encoding == "gzip" else page
        body = pages[key]
        del response.headers["Content-Length"]
        response.headers["Content-Length"] = str(len(body))
        response.body = body
        return response

    return process_request


@contextmanager
def _guarded_serve(guard: AccessGuard) -> Iterator[None]:
    """While inside, every ``websockets.asyncio.server.serve`` call gets ``guard`` in front of
    its ``process_request``."""
    with _SWAP_LOCK:
        original = websockets.asyncio.server.serve

        def serve(*args: Any, **kwargs: Any) -> websockets.asyncio.server.serve:
            inner = with_page_script(kwargs.get("process_request"))
            kwargs["process_request"] = guard.process_request(inner)
            guard.installed += 1
            return original(*args, **kwargs)

        websockets.asyncio.server.serve = serve  # type: ignore[misc,assignment]
        try:
            yield
        finally:
            websockets.asyncio.server.serve = original  # type: ignore[misc]


def start_server(host: str, port: int, label: str, guard: AccessGuard) -> ViewerServer:
    """A running viser server on ``host``:``port`` (or the next free port) behind ``guard``;
    raises AccessNotInstalled (after stopping it) if viser bypassed the guard."""
    if viser.__version__ != TESTED_VISER:
        log.warning(
            "viser %s is not the version the viewer's access shim was tested with (%s); "
            "the viewer checks below that its guard is in place",
            viser.__version__,
            TESTED_VISER,
        )
    # The capture swallows viser's start-up banner (this thread's rich output only): it shows
    # the address without the token, which answers 403; fleet viewer prints the real URL.
    logging.getLogger("websockets.server").addFilter(_HANDSHAKE_NOISE)  # idempotent: one object
    with _guarded_serve(guard), rich.get_console().capture():
        server = ViewerServer(host=host, port=port, label=label)
    if guard.installed == 0:
        server.stop()
        raise AccessNotInstalled(
            f"viser {viser.__version__} started its web server without calling "
            "websockets.asyncio.server.serve, so the viewer's token and Origin check are not in "
            f"front of it; the viewer will not run unguarded. viewer/server.py was written for "
            f"viser {TESTED_VISER}: install that version or update the shim"
        )
    return server
