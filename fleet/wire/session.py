"""Zenoh session configuration shared by every process of the fleet.

Multicast scouting is off everywhere; processes meet on explicit endpoints (the inventory's).
Everything but the router runs in client mode: a client opens no listening socket of its own,
so no process binds to a network we did not choose.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from typing import Literal

import zenoh

log = logging.getLogger("fleet.session")

Mode = Literal["router", "peer", "client"]


@dataclass(frozen=True)
class Credentials:
    """How a session proves who it is, and whom it trusts (``fleet/security`` builds them from
    the inventory). ``ca``: the authority that signed the other side's certificate; ``cert`` and
    ``key``: ours (mutual TLS); ``user``/``password``: Zenoh's user-password authentication (on
    a TLS link, so the password is never sent in clear); ``dictionary``: the router's file of
    ``user:password`` lines."""

    ca: str | None = None
    cert: str | None = None
    key: str | None = None
    mtls: bool = False
    user: str | None = None
    password: str | None = None
    dictionary: str | None = None


def _apply(config: zenoh.Config, mode: Mode, credentials: Credentials) -> None:
    tls = "transport/link/tls"
    if credentials.ca is not None:
        config.insert_json5(f"{tls}/root_ca_certificate", json.dumps(credentials.ca))
    if credentials.mtls:
        config.insert_json5(f"{tls}/enable_mtls", "true")
    if credentials.cert is not None and credentials.key is not None:
        # A router presents its certificate to clients, and to the routers it connects to.
        sides = ("listen", "connect") if mode == "router" else ("connect",)
        for side in sides:
            config.insert_json5(f"{tls}/{side}_certificate", json.dumps(credentials.cert))
            config.insert_json5(f"{tls}/{side}_private_key", json.dumps(credentials.key))
    usrpwd = "transport/auth/usrpwd"
    if credentials.user is not None and credentials.password is not None:
        config.insert_json5(f"{usrpwd}/user", json.dumps(credentials.user))
        config.insert_json5(f"{usrpwd}/password", json.dumps(credentials.password))
    if credentials.dictionary is not None:
        config.insert_json5(f"{usrpwd}/dictionary_file", json.dumps(credentials.dictionary))


LEASE_S = 3.0
"""Zenoh transport lease. The default (10 s) would let a dead agent look alive for 10 s; 3 s
with 4 keep-alives per lease detects a vanished peer in about 3 s without flapping on a loaded
2-core host. Agent and arm liveness is watched faster by heartbeats, not by this lease."""


ROUTER_BLOCK_WAIT_S = 0.5
"""How long a router waits for a session that stops reading before it closes it."""


def zenoh_config(
    mode: Mode,
    connect: list[str] | tuple[str, ...] = (),
    listen: list[str] | tuple[str, ...] = (),
    connect_timeout_s: float = 10.0,
    credentials: Credentials | None = None,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off and only the given endpoints."""
    config: zenoh.Config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "true" if mode == "router" else "false")
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("transport/link/tx/lease", json.dumps(int(LEASE_S * 1000)))
    config.insert_json5("transport/link/tx/keep_alive", "4")
    if mode == "router":
        # A session that stops reading (a frozen viewer) fills the router's queue towards it;
        # on a BLOCK message the router waits this long before closing that session, and routes
        # nothing meanwhile. Zenoh's 5 s would hold every stop up for 5 s per stuck session.
        config.insert_json5(
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            json.dumps(int(ROUTER_BLOCK_WAIT_S * 1e6)),
        )
    if mode == "client":
        # Keep trying the router for a while: the router may be starting at the same time.
        config.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_s * 1000)))
    if credentials is not None:
        _apply(config, mode, credentials)
    return config


class RouterUnreachable(ConnectionError):
    """No router answered on the inventory's endpoints."""


def open_client(
    endpoints: list[str] | tuple[str, ...],
    connect_timeout_s: float = 10.0,
    credentials: Credentials | None = None,
) -> zenoh.Session:
    """A client session connected to the fleet's router(s); RouterUnreachable if none answers
    (or none accepts our credentials)."""
    config = zenoh_config(
        "client", connect=endpoints, connect_timeout_s=connect_timeout_s, credentials=credentials
    )
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        log.debug("zenoh.open failed: %s", exc)  # Zenoh's text names Rust source files
        raise RouterUnreachable(
            f"no Zenoh router answered on {', '.join(endpoints)} within {connect_timeout_s:g} s; "
            "is `fleet router` running? (--connect-timeout S waits longer)"
        ) from None
