"""Who may use the viewer's web server: a token and an Origin allow-list.

The threat: browsers let any page open a WebSocket to any address, ``ws://127.0.0.1:8080``
included, and the same-origin policy does not apply to WebSockets. Without a check, a page in
another tab of the operator's browser could connect to the local viewer and press its buttons
(reset a latched fleet, jog an arm). So every HTTP request and every WebSocket upgrade passes
``AccessPolicy.decide`` before viser sees it:

- **Token.** A random token (``secrets``), kept for the fleet across the viewer's restarts
  (fleet/web/token_store.py: its open tabs keep working), printed in the URL
  (``/?token=...``). A page load that carries the right token is redirected to the same page
  without it (so it stays out of the address bar and history) and gets a cookie holding the
  token (``HttpOnly``, ``SameSite=Strict``, one name per port). viser's client opens its
  WebSocket on the page's own host with no query string (``ws://127.0.0.1:8080/``), so the
  cookie is what carries the token to the upgrade; scripts may put ``?token=...`` on the
  WebSocket URL instead. Without the token: 403 (a page saying to open the printed URL).
- **Origin.** A browser always sends the ``Origin`` of the page that opens a WebSocket, and a
  page cannot forge it. An upgrade must come from the viewer's own origin
  (``http://127.0.0.1:<port>``, ``http://localhost:<port>``, the bound address) or an
  ``--allow-origin`` one; any request with another ``Origin`` is refused. This covers what the
  cookie cannot: a page on another port of the same host is "same-site", so ``SameSite`` does
  not keep the cookie from it.

``AccessPolicy`` is pure (no I/O); ``AccessGuard`` adapts it to a websockets ``process_request``.
"""

from __future__ import annotations

import hmac
import http
import logging
import re
import secrets
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal
from urllib.parse import parse_qsl, urlencode, urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from fleet.web.refusals import Refusals

log = logging.getLogger("fleet.web.access")

TOKEN_PARAM = "token"
FOXGLOVE_TOKEN_ENV = "D1_FLEET_FOXGLOVE_TOKEN"
"""``fleet foxglove``'s token from the environment (how ``fleet demo`` hands it to its child)."""
_TOKEN = re.compile(r"[A-Za-z0-9_-]{16,128}")
_ORIGIN = re.compile(r"https?://[A-Za-z0-9.\-\[\]:]+")
WILDCARD_HOSTS = ("0.0.0.0", "::", "")
"""Bind addresses that are not an address a browser can use in a URL."""

ProcessRequest = Callable[[ServerConnection, Request], Response | None]

FORBIDDEN_PAGE = b"""<!doctype html><html><head><meta charset="utf-8">
<title>d1-fleet viewer</title></head><body style="font-family:sans-serif">
<h1>d1-fleet viewer: access refused</h1>
<p>Open the URL that <code>fleet viewer</code> printed when it started: it carries a token for
this run (<code>http://127.0.0.1:&lt;port&gt;/?token=...</code>). A restarted viewer of the
same fleet keeps its token; one started with a new token (<code>--new-token</code>,
<code>--token</code>) printed a new URL.</p></body></html>
"""
SECURITY_HEADERS = (
    # No other page may frame the viewer: a framed viewer would carry its own origin and the
    # cookie (pages on another port of the host are same-site) and could be clickjacked.
    ("X-Frame-Options", "DENY"),
    ("Content-Security-Policy", "frame-ancestors 'none'"),
    ("Referrer-Policy", "no-referrer"),
)


def new_token() -> str:
    """A fresh random token (32 URL-safe characters)."""
    return secrets.token_urlsafe(24)


def check_token(token: str) -> str:
    """``token`` if usable in a URL and a cookie as is; raises ValueError otherwise."""
    if not _TOKEN.fullmatch(token):
        raise ValueError(
            "a viewer token is 16 to 128 characters of A-Z, a-z, 0-9, '-' and '_' "
            "(leave --token out and the viewer makes a random one)"
        )
    return token


def check_origin(origin: str) -> str:
    """``origin`` normalized (lower case, no trailing slash); raises ValueError unless it is
    ``scheme://host[:port]`` as a browser sends it in the ``Origin`` header."""
    normalized = origin.strip().lower().rstrip("/")
    if not _ORIGIN.fullmatch(normalized):
        raise ValueError(
            f"{origin!r} is not an origin: expected scheme://host[:port] with no path, "
            "e.g. http://robot-pc.lab:8080"
        )
    return normalized


def url_host(host: str) -> str:
    """The host as written in a URL: 127.0.0.1 for a wildcard bind, IPv6 in brackets."""
    if host in WILDCARD_HOSTS:
        return "127.0.0.1"
    return f"[{host}]" if ":" in host else host


@dataclass(frozen=True)
class RequestView:
    """What the policy looks at in one HTTP request."""

    target: str
    """The request target: path and query (``/?token=...``)."""
    origin: str | None
    upgrade: bool
    """True when the request asks for a WebSocket."""
    cookies: str = ""
    """Every ``Cookie`` header, joined with ``;``."""


@dataclass(frozen=True)
class Decision:
    """``pass``: hand the request to viser; ``enter``: redirect to ``location`` and set the
    token cookie; ``refuse``: 403 (``reason`` is logged, never sent)."""

    verdict: Literal["pass", "enter", "refuse"]
    reason: str = ""
    location: str = ""


@dataclass(frozen=True)
class AccessPolicy:
    """The token and the origins the viewer accepts. Pure."""

    token: str
    host: str = "127.0.0.1"
    allow_origins: tuple[str, ...] = ()
    allow_no_origin: bool = False
    """Admit an upgrade without an ``Origin`` (no browser: a desktop app or a script) when it
    carries the token: ``fleet foxglove`` does; viser's clients are browsers, the viewer does
    not."""

    def __post_init__(self) -> None:
        check_token(self.token)
        normalized = tuple(check_origin(origin) for origin in self.allow_origins)
        object.__setattr__(self, "allow_origins", normalized)

    def origins(self, port: int) -> frozenset[str]:
        """The origins a WebSocket upgrade may come from, for the viewer on ``port``."""
        hosts = {"127.0.0.1", "localhost", url_host(self.host)}
        return frozenset({f"http://{host}:{port}" for host in hosts} | set(self.allow_origins))

    def cookie_name(self, port: int) -> str:
        """The token cookie's name: per port, since a browser's cookies ignore the port and
        two viewers on one host must not overwrite each other's."""
        return f"d1fleet-viewer-{port}"

    def set_cookie(self, port: int) -> str:
        """The ``Set-Cookie`` value given with the redirect."""
        return f"{self.cookie_name(port)}={self.token}; Path=/; HttpOnly; SameSite=Strict"

    def _matches(self, supplied: str | None) -> bool:
        return supplied is not None and hmac.compare_digest(
            supplied.encode("utf-8", "replace"), self.token.encode()
        )

    def _cookie_ok(self, cookies: str, port: int) -> bool:
        name = self.cookie_name(port)
        for part in cookies.split(";"):
            key, sep, value = part.strip().partition("=")
            if sep and key == name and self._matches(value):
                return True
        return False

    def decide(self, request: RequestView, port: int) -> Decision:
        """What to do with ``request`` arriving at the viewer on ``port``."""
        if request.origin is not None and request.origin.lower() not in self.origins(port):
            return Decision("refuse", f"Origin {request.origin!r} is not one of the viewer's")
        if request.upgrade and request.origin is None and not self.allow_no_origin:
            return Decision("refuse", "a WebSocket upgrade without an Origin header")
        split = urlsplit(request.target)
        params = parse_qsl(split.query, keep_blank_values=True)
        given = [value for key, value in params if key == TOKEN_PARAM]
        cookie_ok = self._cookie_ok(request.cookies, port)
        if request.upgrade:
            if cookie_ok or any(self._matches(value) for value in given):
                return Decision("pass")
            return Decision("refuse", "a WebSocket upgrade without this run's token")
        if given:
            if not all(self._matches(value) for value in given):
                return Decision("refuse", "a page request with a wrong token")
            # "/" + lstrip: never "//host", which a browser would take for another site.
            rest = urlencode([(k, v) for k, v in params if k != TOKEN_PARAM])
            location = "/" + split.path.lstrip("/") + (f"?{rest}" if rest else "")
            return Decision("enter", location=location)
        if cookie_ok:
            return Decision("pass")
        return Decision("refuse", f"a request for {split.path or '/'!r} without this run's token")


def request_view(request: Request) -> RequestView:
    """The parts of a websockets ``Request`` the policy reads."""
    headers = request.headers
    origins = headers.get_all("Origin")
    return RequestView(
        target=request.path,
        # Two Origin headers join into one value that matches no allowed origin: refused.
        origin=", ".join(origins) if origins else None,
        upgrade=any("websocket" in value.lower() for value in headers.get_all("Upgrade")),
        cookies="; ".join(headers.get_all("Cookie")),
    )


class AccessGuard:
    """The policy in front of viser's own ``process_request`` (which serves its page and
    returns None for an upgrade, letting the WebSocket open)."""

    def __init__(self, policy: AccessPolicy) -> None:
        self.policy = policy
        self.refusals = Refusals(log)
        self.installed = 0
        """How many websockets servers were started with this guard in front (see server.py)."""

    def process_request(self, inner: ProcessRequest | None) -> ProcessRequest:
        """A ``process_request`` that decides first and calls ``inner`` only for a pass.

        Runs on viser's event loop: pure work, no I/O, no lock held long."""

        def process_request(connection: ServerConnection, request: Request) -> Response | None:
            port = int(connection.local_address[1])
            view = request_view(request)
            decision = self.policy.decide(view, port)
            if decision.verdict == "refuse":
                kind = "websocket" if view.upgrade else "page"
                self.refusals.refuse(kind, f"{decision.reason} (port {port})")
                return _forbidden(view.upgrade)
            if decision.verdict == "enter":
                return _redirect(decision.location, self.policy.set_cookie(port))
            response = inner(connection, request) if inner is not None else None
            if response is not None:
                for name, value in SECURITY_HEADERS:
                    response.headers[name] = value
            return response

        return process_request


def _forbidden(upgrade: bool) -> Response:
    body = b"403 Forbidden: open the URL fleet viewer printed\n" if upgrade else FORBIDDEN_PAGE
    kind = "text/plain" if upgrade else "text/html"
    headers = Headers(
        [
            ("Content-Type", f"{kind}; charset=utf-8"),
            ("Content-Length", str(len(body))),
            ("Cache-Control", "no-store"),
            ("Connection", "close"),
            *SECURITY_HEADERS,
        ]
    )
    status = http.HTTPStatus.FORBIDDEN
    return Response(status.value, status.phrase, headers, body)


def _redirect(location: str, cookie: str) -> Response:
    headers = Headers(
        [
            ("Location", location),
            ("Set-Cookie", cookie),
            ("Content-Length", "0"),
            ("Cache-Control", "no-store"),
            ("Connection", "close"),
            *SECURITY_HEADERS,
        ]
    )
    status = http.HTTPStatus.SEE_OTHER
    return Response(status.value, status.phrase, headers, b"")
