"""Who may use the viewer's web server (fleet/web/access.py, viewer/server.py): the token, the
Origin allow-list and the share tunnel, checked with a plain ``websockets`` client and plain
HTTP against a real viser server on loopback (the browser's view is in test_viewer_browser.py).
"""

from __future__ import annotations

import http.client
import inspect
import logging
import os
import struct
import time
from collections.abc import Iterator
from typing import Any

import msgspec
import pytest
import viser
import viser.infra._infra
import websockets.asyncio.server
import zstandard
from viser import _messages
from websockets.sync.client import ClientConnection

from fleet.web.access import (
    AccessGuard,
    AccessPolicy,
    Decision,
    RequestView,
    check_origin,
    check_token,
)
from fleet.web.refusals import Refusals
from testkit.harness import free_port
from testkit.sockets import loopback_only, ws
from viewer import server as viewer_server
from viewer.server import TESTED_VISER, AccessNotInstalled, ViewerServer, start_server

TOKEN = "t0ken-for-the-tests_0123456789"
ROBOT_PC = "http://robot-pc.lab:8080"


# ---------------------------------------------------------------------- the pure policy


def test_policy_decides_on_token_cookie_and_origin() -> None:
    policy = AccessPolicy(token=TOKEN, allow_origins=(ROBOT_PC + "/",))
    own, cookie = "http://127.0.0.1:8080", f"d1fleet-viewer-8080={TOKEN}"

    def decide(target: str, origin: str | None, upgrade: bool, cookies: str = "") -> Decision:
        return policy.decide(RequestView(target, origin, upgrade, cookies), 8080)

    # A page load: the token in the query enters (redirect without it), the cookie passes.
    assert decide(f"/?token={TOKEN}", None, False) == Decision("enter", location="/")
    assert decide(f"/?a=1&token={TOKEN}", None, False).location == "/?a=1"
    assert decide(f"////evil.example/?token={TOKEN}", None, False).location == "/evil.example/"
    assert decide("/", None, False, cookie).verdict == "pass"
    assert decide("/", None, False, f"other=1; {cookie}").verdict == "pass"
    for refused in (
        decide("/", None, False),
        decide("/?token=wrong-token-0123456789", None, False),
        decide(f"/?token={TOKEN}&token=x", None, False),
        decide("/", None, False, f"d1fleet-viewer-8081={TOKEN}"),  # another viewer's cookie
        decide("/", None, False, "d1fleet-viewer-8080=wrong-token-0123456789"),
        decide("/", "http://evil.example", False, cookie),  # a foreign page's fetch
    ):
        assert refused.verdict == "refuse", refused

    # A WebSocket upgrade: the token (cookie or query) and one of the viewer's origins.
    for origin in (own, "http://localhost:8080", ROBOT_PC, "HTTP://LOCALHOST:8080"):
        assert decide("/", origin, True, cookie).verdict == "pass", origin
    assert decide(f"/?token={TOKEN}", own, True).verdict == "pass"
    for refused in (
        decide("/", own, True),  # no token
        decide("/?token=wrong-token-0123456789", own, True),
        decide("/", "http://evil.example", True, cookie),
        decide("/", "http://127.0.0.1:8081", True, cookie),  # another port: same site, not us
        decide("/", "null", True, cookie),  # a sandboxed frame or a file:// page
        decide("/", None, True, cookie),  # a browser always sends Origin
        decide("/", f"{own}, {own}", True, cookie),  # two Origin headers
    ):
        assert refused.verdict == "refuse", refused


def test_bound_address_is_an_own_origin_and_wildcards_are_not() -> None:
    assert "http://10.0.0.5:8080" in AccessPolicy(TOKEN, host="10.0.0.5").origins(8080)
    assert AccessPolicy(TOKEN, host="0.0.0.0").origins(8080) == {
        "http://127.0.0.1:8080",
        "http://localhost:8080",
    }


def test_tokens_and_origins_are_checked_where_they_are_given() -> None:
    assert check_token(TOKEN) == TOKEN
    for bad in ("short", "x" * 129, "has space in it 0123", "semi;colon-0123456789"):
        with pytest.raises(ValueError, match="16 to 128"):
            check_token(bad)
    with pytest.raises(ValueError):
        AccessPolicy(token="short")
    assert check_origin("HTTP://Robot-PC.lab:8080/") == ROBOT_PC
    for bad in ("robot-pc.lab:8080", "http://robot-pc.lab:8080/viewer", "*"):
        with pytest.raises(ValueError, match="not an origin"):
            check_origin(bad)


# ---------------------------------------------------------------------- a real server


@pytest.fixture
def server() -> Iterator[ViewerServer]:
    guard = AccessGuard(AccessPolicy(token=TOKEN, allow_origins=(ROBOT_PC,)))
    started = start_server("127.0.0.1", free_port(), "access test", guard)
    try:
        yield started
    finally:
        started.stop()


def viser_messages(connection: ClientConnection, until_s: float) -> Iterator[dict[str, Any]]:
    """Messages the server sends, decoded (viser's frame: two little-endian u64 sizes, zstd
    msgpack, binary buffers after it)."""
    deadline = time.monotonic() + until_s
    while time.monotonic() < deadline:
        try:
            raw = connection.recv(timeout=max(0.01, deadline - time.monotonic()))
        except TimeoutError:
            return
        assert isinstance(raw, bytes)
        size, compressed = struct.unpack_from("<QQ", raw)
        inner = zstandard.ZstdDecompressor().decompress(raw[16 : 16 + compressed], size)
        yield from msgspec.msgpack.decode(inner)["messages"]


def test_websocket_without_the_token_is_refused(server: ViewerServer) -> None:
    port = server.get_port()
    own = f"http://127.0.0.1:{port}"
    assert ws(port, own) == 403
    assert ws(port, own, cookie=f"d1fleet-viewer-{port}=wrong-token-0123456789") == 403
    assert ws(port, own, cookie=f"d1fleet-viewer-{port + 1}={TOKEN}") == 403
    assert ws(port, own, query="?token=wrong-token-0123456789") == 403


def test_websocket_from_another_origin_is_refused_even_with_the_token(
    server: ViewerServer,
) -> None:
    port = server.get_port()
    cookie = f"d1fleet-viewer-{port}={TOKEN}"
    for origin in ("http://evil.example", f"http://127.0.0.1:{port + 1}", "null", None):
        assert ws(port, origin, cookie=cookie) == 403, origin


def test_websocket_with_the_token_and_an_own_origin_is_accepted(server: ViewerServer) -> None:
    port = server.get_port()
    for origin, cookie, query in (
        (f"http://127.0.0.1:{port}", f"d1fleet-viewer-{port}={TOKEN}", ""),
        (f"http://localhost:{port}", None, f"?token={TOKEN}"),
        (ROBOT_PC, f"d1fleet-viewer-{port}={TOKEN}", ""),
    ):
        connection = ws(port, origin, cookie=cookie, query=query)
        assert isinstance(connection, ClientConnection), (origin, connection)
        with connection:
            assert any(True for _ in viser_messages(connection, 2.0)), "no state from viser"


def get(port: int, target: str, cookie: str | None = None) -> http.client.HTTPResponse:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=5.0)
    connection.request("GET", target, headers={"Cookie": cookie} if cookie else {})
    response = connection.getresponse()
    response.read()
    connection.close()
    return response


def test_page_needs_the_token_and_the_token_url_sets_the_cookie(server: ViewerServer) -> None:
    port = server.get_port()
    for target in ("/", "/index.html", "/?token=wrong-token-0123456789"):
        assert get(port, target).status == 403, target
    entered = get(port, f"/?token={TOKEN}")
    assert entered.status == 303 and entered.getheader("Location") == "/"
    cookie = entered.getheader("Set-Cookie")
    assert cookie == f"d1fleet-viewer-{port}={TOKEN}; Path=/; HttpOnly; SameSite=Strict"
    page = get(port, "/", cookie=cookie.split(";")[0])
    assert page.status == 200 and page.getheader("Content-Type", "").startswith("text/html")
    assert page.getheader("X-Frame-Options") == "DENY"  # no other page may frame it


# ---------------------------------------------------------------------- the shim and viser


def test_the_shim_matches_the_viser_it_was_written_for() -> None:
    """If this fails, viser changed: re-read viewer/server.py's docstring and check that viser
    still starts its server with websockets.asyncio.server.serve(process_request=...)."""
    assert viser.__version__ == TESTED_VISER
    source = inspect.getsource(viser.infra._infra.WebsockServer._background_worker)
    assert "websockets.asyncio.server.serve(" in source
    assert "process_request=" in source
    assert "request_share_url" in inspect.getsource(viser.ViserServer.__init__)


def test_the_swap_is_undone_and_a_bypassed_guard_refuses_to_start(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    original = websockets.asyncio.server.serve
    guard = AccessGuard(AccessPolicy(token=TOKEN))
    start_server("127.0.0.1", free_port(), "swap", guard).stop()
    assert guard.installed == 1
    assert websockets.asyncio.server.serve is original

    # A viser that started its server some other way: the guard is never called.
    monkeypatch.setattr(viewer_server, "_guarded_serve", lambda _guard: _nothing())
    with pytest.raises(AccessNotInstalled, match="will not run unguarded"):
        start_server("127.0.0.1", free_port(), "bypassed", AccessGuard(AccessPolicy(TOKEN)))


class _nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


# ---------------------------------------------------------------------- the share tunnel


def test_the_share_button_is_off_and_its_request_opens_nothing(server: ViewerServer) -> None:
    from tests.e2e.test_viewer_control import panels_on  # the viewer's real panels

    port = server.get_port()
    panels_on(server, read_only=False)
    connection = ws(port, f"http://127.0.0.1:{port}", query=f"?token={TOKEN}")
    assert isinstance(connection, ClientConnection)
    with connection:
        themes = [
            message
            for message in viser_messages(connection, 3.0)
            if message["type"] == "ThemeConfigurationMessage"
        ]
        assert themes and all(t["show_share_button"] is False for t in themes), themes
        # The button is hidden, but any client can send its message: it must open nothing.
        request = _messages.ShareUrlRequest().as_serializable_dict()
        connection.send(msgspec.msgpack.encode(request))
        deadline = time.monotonic() + 5.0
        while server.share_refusals["share"] == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
    assert server.share_refusals["share"] == 1
    assert server._share_tunnel is None
    assert loopback_only(os.getpid()) == []


def test_refusals_are_counted_and_logged_rate_limited(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    refusals = Refusals(logging.getLogger("test.refusals"), interval_s=5.0, clock=lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="test.refusals"):
        for _ in range(100):
            refusals.refuse("websocket", "no token")
        refusals.refuse("page", "no token")
        now[0] = 5.0
        refusals.refuse("websocket", "no token")
    assert refusals["websocket"] == 101 and refusals["page"] == 1
    lines = [r.getMessage() for r in caplog.records]
    assert lines == [
        "refused: no token",
        "refused: no token",
        "refused: no token (and 99 more since the last report)",
    ]


def test_a_flood_of_refused_handshakes_logs_a_line_not_a_flood(
    server: ViewerServer, caplog: pytest.LogCaptureFixture
) -> None:
    port = server.get_port()
    with caplog.at_level(logging.INFO):
        for _ in range(30):
            assert ws(port, "http://evil.example") == 403
    websocket_lines = [r for r in caplog.records if r.name.startswith("websockets")]
    refusals = [r for r in caplog.records if r.name == "fleet.web.access"]
    assert websocket_lines == [] and len(refusals) == 1
