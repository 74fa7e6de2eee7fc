"""The door in front of ``fleet foxglove``: the viewer's token and Origin checks (issue 28, item 3).

Foxglove's SDK server checks neither a token nor the ``Origin`` of a WebSocket, and a page in any
tab of the operator's browser may open a WebSocket to ``ws://127.0.0.1:8765`` (a page from
``http://evil.example`` received 17-27 live channels). So the SDK server listens on a private
port and ``FoxgloveGate``, a small WebSocket proxy on the public port, lets a client through
only after ``fleet.web.access.AccessPolicy`` passed it:

- the run's token, as ``?token=...`` on the URL (``ws://127.0.0.1:8765/?token=...``: Foxglove's
  "Open connection" takes it as is);
- an ``Origin`` of the allow-list when a browser sent one (the gate's own origins, Foxglove's web
  app ``https://app.foxglove.dev`` and ``--allow-origin`` ones). A client with no ``Origin`` is no
  browser (Foxglove's desktop app, scripts): the token alone admits it.

The private port is on loopback with TLS under a certificate made for this run, which only the
gate trusts: a browser cannot open it (an unknown certificate fails a ``wss://`` handshake with
no prompt), so a page scanning loopback ports finds no way around the gate.

Threads: websockets' threaded server (no asyncio here), a thread per client and one more per
client for the direction server -> client. At most ``MAX_CLIENTS`` clients. Shutdown: stop
accepting -> close every client's two connections -> join their threads (bounded).
"""

from __future__ import annotations

import datetime
import http
import ipaddress
import logging
import ssl
import threading
from dataclasses import dataclass

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed, InvalidHandshake
from websockets.http11 import Request, Response
from websockets.sync.client import ClientConnection, connect
from websockets.sync.server import Server, ServerConnection, serve

from fleet.guard import ThreadGuard
from fleet.web.access import AccessPolicy, request_view
from fleet.web.refusals import Refusals

log = logging.getLogger("fleet.foxglove")

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
"""What clients may offer: the protocol's name in Foxglove's SDK, and its first name, which
older Foxglove apps, Lichtblick and Foxglove's ws-protocol clients still offer."""
UPSTREAM_SUBPROTOCOL = "foxglove.sdk.v1"
"""The one name the SDK's server (foxglove-sdk 0.30) accepts: it answers HTTP 400 to
``foxglove.websocket.v1``. The two name one protocol (Foxglove's stance, and what Lichtblick
and Flora rely on to accept both), so the gate opens the private server with this name
whatever the client offered, and copies the frames as they are."""
FOXGLOVE_APP_ORIGIN = "https://app.foxglove.dev"
"""Foxglove's web app: allowed by default (its pages still need the token)."""
MAX_CLIENTS = 16
CLIENT_MESSAGE_BYTES = 1 << 20
"""A client's own messages (subscribe, unsubscribe...) are small."""
SERVER_MESSAGE_BYTES = 64 << 20
LOOPBACK = "127.0.0.1"
UPSTREAM_TRIES = 2
UPSTREAM_OPEN_S = 5.0
"""Each try's wait for the private server's WebSocket handshake."""
CLOSE_S = 1.0
"""How long closing a connection waits for the other side's close frame (websockets' default,
10 s, held ``fleet foxglove``'s shutdown that long when a client and its pumps closed at once)."""


@dataclass(frozen=True)
class PrivateTls:
    """The private server's certificate and key (PEM), made for one run, and the client-side
    context that trusts exactly it."""

    cert_pem: bytes
    key_pem: bytes

    @classmethod
    def make(cls) -> PrivateTls:
        """A fresh self-signed P-256 certificate for 127.0.0.1, valid for a week."""
        key = ec.generate_private_key(ec.SECP256R1())
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "d1-fleet foxglove (private)")])
        now = datetime.datetime.now(datetime.UTC)
        cert = (
            x509.CertificateBuilder()
            .subject_name(name)
            .issuer_name(name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=7))
            .add_extension(
                x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address(LOOPBACK))]),
                critical=False,
            )
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(key, hashes.SHA256())
        )
        key_pem = key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
        return cls(cert.public_bytes(serialization.Encoding.PEM), key_pem)

    def client_context(self) -> ssl.SSLContext:
        """A TLS client context trusting only this certificate."""
        context = ssl.create_default_context(cadata=self.cert_pem.decode())
        return context


class FoxgloveGate:
    """A token- and Origin-checking WebSocket proxy on ``host:port`` in front of the private
    Foxglove server on ``wss://127.0.0.1:<upstream_port>``. A context manager."""

    def __init__(
        self,
        policy: AccessPolicy,
        host: str,
        port: int,
        upstream_port: int,
        tls: PrivateTls,
        guard: ThreadGuard,
    ) -> None:
        self.policy = policy
        self.refusals = Refusals(log)
        self.admitted = 0
        self._upstream = f"wss://{LOOPBACK}:{upstream_port}/"
        self._tls = tls.client_context()
        self._guard = guard
        self._lock = threading.Lock()  # guards _clients
        self._clients: dict[ServerConnection, ClientConnection | None] = {}
        self._closed = False
        self._server: Server = serve(
            guard.wrap(self._handle, "foxglove-gate-client"),
            host,
            port,
            process_request=self._process_request,
            subprotocols=list(SUBPROTOCOLS),  # type: ignore[arg-type]
            max_size=CLIENT_MESSAGE_BYTES,
            compression=None,
            close_timeout=CLOSE_S,
        )
        self.port = int(self._server.socket.getsockname()[1])
        self._thread = guard.thread(self._server.serve_forever, "foxglove-gate")
        self._thread.start()

    def url(self, host: str) -> str:
        """The URL to open in Foxglove (with the token)."""
        return f"ws://{host}:{self.port}/?token={self.policy.token}"

    def _process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        view = request_view(request)
        decision = self.policy.decide(view, self.port)
        if decision.verdict != "pass" or not view.upgrade:
            why = decision.reason or "not a WebSocket upgrade (this port is for Foxglove)"
            self.refusals.refuse("websocket" if view.upgrade else "page", why)
            return _refused(http.HTTPStatus.FORBIDDEN, "open the URL fleet foxglove printed")
        return None

    def _handle(self, client: ServerConnection) -> None:
        """One admitted client's thread: open the private server (``UPSTREAM_SUBPROTOCOL``),
        then copy both ways until either side closes."""
        with self._lock:
            admit = not self._closed and len(self._clients) < MAX_CLIENTS
            if admit:
                self._clients[client] = None
        if not admit:
            self.refusals.refuse("websocket", f"more than {MAX_CLIENTS} clients")
            client.close(1013, "too many Foxglove clients")
            return
        try:
            upstream = self._open_upstream(client)
            if upstream is None:
                client.close(1011, "the Foxglove server is not available")
                return
            with self._lock:
                closed = self._closed
                if not closed:
                    self._clients[client] = upstream
            if closed:
                upstream.close()
                client.close(1001, "fleet foxglove is stopping")
                return
            self.admitted += 1
            back = self._guard.thread(lambda: _pump(upstream, client), "foxglove-gate-out")
            back.start()
            _pump(client, upstream)
            back.join(timeout=5.0)
        finally:
            with self._lock:
                self._clients.pop(client, None)

    def _open_upstream(self, client: ServerConnection) -> ClientConnection | None:
        """The private server, with the SDK's subprotocol; None if it did not answer.
        Tried twice: on a loaded host its handshake once took more than 5 s (measured at load
        6-9), and a client that waits a little longer is better served than refused."""
        for attempt in range(UPSTREAM_TRIES):
            try:
                return connect(
                    self._upstream,
                    ssl=self._tls,
                    subprotocols=[UPSTREAM_SUBPROTOCOL],  # type: ignore[list-item]
                    max_size=SERVER_MESSAGE_BYTES,
                    compression=None,
                    open_timeout=UPSTREAM_OPEN_S,
                    close_timeout=CLOSE_S,
                )
            except (OSError, TimeoutError, ConnectionClosed, InvalidHandshake) as exc:
                # A refused handshake (an HTTP status) fails this client only, never the
                # command: it took `fleet foxglove` down (exit 1) for one client.
                log.warning(
                    "foxglove gate: the private server did not answer (%s; try %d of %d)",
                    exc,
                    attempt + 1,
                    UPSTREAM_TRIES,
                )
        return None

    def close(self) -> None:
        """Stop accepting -> close every client -> join (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            pairs = list(self._clients.items())
        self._server.shutdown()
        for client, upstream in pairs:
            client.close(1001, "fleet foxglove is stopping")
            if upstream is not None:
                upstream.close()
        self._thread.join(timeout=5.0)

    def __enter__(self) -> FoxgloveGate:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _pump(
    source: ServerConnection | ClientConnection, sink: ServerConnection | ClientConnection
) -> None:
    """Copy messages from ``source`` to ``sink`` until either closes; then close both."""
    try:
        for message in source:
            sink.send(message)
    except (ConnectionClosed, OSError):  # the peer went away: the other side is closed too
        pass
    finally:
        source.close()
        sink.close()


def _refused(status: http.HTTPStatus, text: str) -> Response:
    body = f"{status.value} {status.phrase}: {text}\n".encode()
    headers = Headers(
        [
            ("Content-Type", "text/plain; charset=utf-8"),
            ("Content-Length", str(len(body))),
            ("Cache-Control", "no-store"),
            ("Connection", "close"),
        ]
    )
    return Response(status.value, status.phrase, headers, body)
