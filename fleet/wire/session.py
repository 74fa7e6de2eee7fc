"""Zenoh session configuration shared by every process of the fleet.

Multicast scouting is off everywhere; processes meet on explicit endpoints (the inventory's).
Everything but the router runs in client mode: a client opens no listening socket of its own,
so no process binds to a network we did not choose.
"""

from __future__ import annotations

import json
import logging
import threading
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
with ``KEEP_ALIVES_PER_LEASE`` keep-alives detects a vanished peer in about 3 s without flapping
on a loaded 2-core host. Agent and arm liveness is watched faster by heartbeats. Not lengthened
for loss (issue 24): at 30 % loss per link TCP's backed-off retransmissions outlast any sensible
lease, so the TCP session closes and reopens as before, and stops take the datagram session."""


KEEP_ALIVES_PER_LEASE = 10
"""Keep-alives per lease, each link (sent only on a link that carried nothing else meanwhile).
Zenoh's default 4 lost in a row closes a link: at 30 % loss per network link (51 % per
client-router path) that is 7 % per lease on the datagram link, which carries nothing but stops,
acks and heartbeats; 10 make it 0.1 %, for 3 idle keep-alives a second."""

DATAGRAM_LEASE_S = 30.0
"""The lease a datagram session gives the router. A Zenoh router's UDP listener is one loop
that hands each datagram to its link through a one-slot mailbox; when the router expires a
UDP session whose peer is still sending, the loop can wait for ever to hand a datagram to
the closed link, and no UDP session at that router hears anything again (measured in the
lab at 30 % loss: the router's UDP socket queue full for the rest of the run). A router
expires a session after the session's own lease without a message from it; the datagram
sessions send beats ten times a second, so only a router that processes nothing for this
long expires one. The session's own view of the router keeps the router's 3 s lease."""

ROUTER_BLOCK_WAIT_S = 0.5
"""How long a router waits for a session that stops reading before it closes it (for what
still leaves a router as BLOCK: replies, declarations; see ``NEVER_WAIT_FOR_A_CONSUMER``)."""

ROUTER_DROP_WAIT_US = 50_000
"""How long a router waits for room towards a session before it drops a DROP message (Zenoh's
default is 1 ms). Only the first message waits: while that queue stays full the next ones are
dropped at once (measured: 10 frozen subscribers of a 3 MB/s load left stop -> ack at 2-8 ms).
50 ms, because every put leaves a router as DROP (``NEVER_WAIT_FOR_A_CONSUMER``): with 1 ms a
burst of 600 stops and resets lost its last reset towards a busy agent in 1 of 3 runs (a
kinds safety test), with 50 ms none in 7 runs."""

NEVER_WAIT_FOR_A_CONSUMER: dict[str, object] = {
    "id": "d1_fleet_never_wait_for_a_consumer",
    "messages": ["put", "delete", "query"],
    "flows": ["egress"],
    "key_exprs": ["**"],
    "overwrite": {"congestion_control": "drop"},
}
"""The routers' QoS overwrite (Zenoh ``qos/network``) that makes every put, delete and query
leave a router as DROP, whatever its publisher asked for. A router pushes a message to each
subscriber on the thread that reads the publisher's session, one subscriber after another: a
BLOCK message towards a session that stopped reading (a frozen viewer, an observer's client
suspended on purpose) held that thread ``ROUTER_BLOCK_WAIT_S`` per such session before it
closed it, and with it every session read on that thread (the router has one per core).
Measured with 10 frozen subscribers of ``fleet/<fleet>/**``: one reset (BLOCK) held the
router 5 s, stops went unacknowledged for 10 s. The publisher's own side keeps its BLOCK (its
put waits for its own link, not for anyone else's reader). The price: a reset, a contact
event or a command towards a session whose queue at the router is full is dropped, not
waited for; a dropped reset leaves the unit stopped (reset again), a dropped command times
out at its sender. Replies cannot be overwritten (Zenoh 1.10): they keep their BLOCK and
``ROUTER_BLOCK_WAIT_S``."""
RECONNECT_RETRY = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
"""How often a lost router (or a site router's central one) is tried again. Zenoh's default
backs off to 4 s: a router restarted 1-3 s after it died was found by its clients up to 4 s
after it listened again (measured: 2.0-3.0 s; with these, 0.0-0.25 s); an arm's joints and
acks wait for it. One TCP connect a second per session to a dead router costs nothing."""


@dataclass(frozen=True)
class Datagram:
    """The datagram path of stops (issue 24): beside each ``tcp/`` endpoint the router also
    listens on ``udp/`` at the same address and port, and each process opens a second, small
    Zenoh session over UDP only (``open_datagram``) for the best-effort copies of stops, acks
    and heartbeats. ``dscp``: the DSCP code point (0-63) marked on its packets (None: none).

    Why a session of its own, not a second link of the one session (Zenoh multilink, measured
    first): a multilink session sends reliable messages on the UDP link once its TCP link died
    (at 30 % loss within seconds: TCP's backed-off retransmissions outlast the lease), and
    never reopens the TCP link: after the loss the session stayed on UDP, reliable in name
    only. Two sessions fail separately: the TCP session closes and reopens as before, the
    datagram session keeps carrying stops."""

    enabled: bool = True
    dscp: int | None = None


def datagram_twin(endpoint: str, dscp: int | None = None) -> str | None:
    """The datagram endpoint beside a ``tcp/`` or ``tls/`` one: ``udp/`` at the same address
    and port, or for TLS ``quic/`` there with unreliable datagrams (``rel=0``): QUIC carries TLS
    1.3, so the datagram copies of a secure fleet are authenticated by the same certificates (or
    passwords) and checked by the same access control as its TLS session. None for any other
    protocol."""
    proto, _, rest = endpoint.partition("/")
    if proto not in ("tcp", "tls") or not rest:
        return None
    address = rest.split("#", 1)[0].split("?", 1)[0]
    marks = f"#dscp={dscp << 2}" if dscp is not None else ""  # Zenoh takes the IP TOS byte
    if proto == "tls":
        return f"quic/{address}?rel=0{marks}"
    return f"udp/{address}{marks}"


def datagram_twins(endpoints: list[str] | tuple[str, ...], datagram: Datagram | None) -> list[str]:
    """The datagram twins of ``endpoints`` (none when ``datagram`` is off)."""
    if datagram is None or not datagram.enabled:
        return []
    return [t for t in (datagram_twin(e, datagram.dscp) for e in endpoints) if t is not None]


def zenoh_config(
    mode: Mode,
    connect: list[str] | tuple[str, ...] = (),
    listen: list[str] | tuple[str, ...] = (),
    connect_timeout_s: float = 10.0,
    credentials: Credentials | None = None,
    datagram: Datagram | None = None,
    lease_s: float = LEASE_S,
) -> zenoh.Config:
    """A Zenoh config with multicast scouting off and only the given endpoints (a router with
    ``datagram`` also listens on their datagram twins)."""
    config: zenoh.Config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "true" if mode == "router" else "false")
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("connect/retry", json.dumps(RECONNECT_RETRY))
    twins = datagram_twins(listen, datagram) if mode == "router" else []
    config.insert_json5("listen/endpoints", json.dumps([*listen, *twins]))
    config.insert_json5("transport/link/tx/lease", json.dumps(int(lease_s * 1000)))
    config.insert_json5("transport/link/tx/keep_alive", str(KEEP_ALIVES_PER_LEASE))
    if mode == "router":
        # A session that stops reading (a frozen viewer) fills the router's queue towards it;
        # on a BLOCK message the router waits this long before closing that session, and routes
        # nothing meanwhile. Zenoh's 5 s would hold every stop up for 5 s per stuck session.
        config.insert_json5(
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            json.dumps(int(ROUTER_BLOCK_WAIT_S * 1e6)),
        )
        config.insert_json5(
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop",
            json.dumps(ROUTER_DROP_WAIT_US),
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


def open_datagram(
    endpoints: list[str] | tuple[str, ...],
    datagram: Datagram,
    connect_timeout_s: float = 10.0,
    credentials: Credentials | None = None,
) -> zenoh.Session | None:
    """The datagram session beside a client session (``Datagram``), presenting the same
    ``credentials``, or None when there is no datagram twin (``datagram = false``) or no router
    answers on it (an older router: stops then take the reliable path only, as before;
    logged)."""
    twins = datagram_twins(endpoints, datagram)
    if not twins:
        return None
    config = zenoh_config(
        "client",
        connect=twins,
        connect_timeout_s=connect_timeout_s,
        credentials=credentials,
        lease_s=DATAGRAM_LEASE_S,
    )
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        log.warning(
            "no datagram path for stops: no router answered on %s (%s); stops take the "
            "reliable path only",
            ", ".join(twins),
            str(exc)[:200],
        )
        return None


CLOSE_WAIT_S = 2.0
"""How long closing a session may hold a process's shutdown. Zenoh's own close waits up to
10 s for a link whose router is gone (seen with a QUIC datagram session, and reported for TCP
under loss: eclipse-zenoh/zenoh#2675); a process told to stop must not hang that long."""


def close_bounded(session: zenoh.Session, what: str, timeout_s: float = CLOSE_WAIT_S) -> bool:
    """Close ``session``, waiting at most ``timeout_s``; True if it closed in time. Past that,
    the close goes on on a daemon thread (the process's exit ends it) and a warning says so."""
    if session.is_closed():
        return True

    def close() -> None:
        try:
            session.close()  # type: ignore[no-untyped-call]
        except zenoh.ZError as exc:
            log.warning("closing the %s: %s", what, str(exc)[:200])

    closer = threading.Thread(target=close, name=f"close-{what}", daemon=True)
    closer.start()
    closer.join(timeout_s)
    if closer.is_alive():
        log.warning(
            "closing the %s took over %g s (its router unreachable?): not waiting for it",
            what,
            timeout_s,
        )
        return False
    return True
