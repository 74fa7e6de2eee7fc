"""Zenoh sessions with the inventory's security: every process opens its session here.

``mode = "none"``: plain links, nothing authenticated (the loopback demo). ``mtls``: each side
presents a certificate signed by the fleet's CA; the client's common name is its principal.
``password``: the router presents its certificate (the link is encrypted and the client knows
it talks to the right router), the client a user name and password.
"""

from __future__ import annotations

import json
from pathlib import Path

import zenoh

from fleet.files import FileReadError, read_regular
from fleet.inventory import Inventory, InventoryError
from fleet.security.acl import access_control, payload_limits
from fleet.wire.keys import KeySpace
from fleet.wire.session import (
    NEVER_WAIT_FOR_A_CONSUMER,
    Credentials,
    RouterUnreachable,
    datagram_twins,
    open_client,
    open_datagram,
    zenoh_config,
)
from fleet.wire.stoppath import DatagramSession, stop_qos_overwrite

ROUTER_PRINCIPAL = "router"
PASSWORD_ENV = "D1_FLEET_PASSWORD"


def _password_of(inventory: Inventory, principal: str) -> str:
    """The password of ``principal``: $D1_FLEET_PASSWORD, else its line in the passwords file
    (on a real site each host keeps only its own line)."""
    import os

    given = os.environ.get(PASSWORD_ENV)
    if given:
        return given
    path = Path(inventory.security.passwords)
    try:
        text = read_regular(path, what="passwords file").decode("utf-8", "replace")
    except (OSError, FileReadError) as exc:
        raise InventoryError(f"{inventory.path}: security.passwords: {exc}") from None
    lines = text.splitlines()
    for line in lines:
        user, _, password = line.partition(":")
        if user == principal and password:
            return password
    raise InventoryError(
        f"{inventory.path}: no password for {principal!r} in {path} (or set ${PASSWORD_ENV})"
    )


def credentials(inventory: Inventory, principal: str, router: bool = False) -> Credentials | None:
    """What a session of ``principal`` presents (None: plain links)."""
    security = inventory.security
    if not security.enabled:
        return None
    plain = [e for e in inventory.endpoints if not e.startswith("tls/")]
    if plain:
        raise InventoryError(
            f"{inventory.path}: security mode {security.mode!r} needs tls/ endpoints "
            f"(not {', '.join(plain)}): credentials must never cross a plain link"
        )
    for needed in (security.ca, *security.cert(principal)) if security.mode == "mtls" else ():
        if not Path(needed).is_file():
            raise InventoryError(
                f"{inventory.path}: {needed} is missing: run `fleet certs` for the inventory "
                f"(or copy {principal!r}'s certificate and key there)"
            )
    cert, key = security.cert(principal)
    if security.mode == "mtls":
        return Credentials(ca=security.ca, cert=cert, key=key, mtls=True)
    if router:
        return Credentials(ca=security.ca, cert=cert, key=key, dictionary=security.passwords)
    return Credentials(ca=security.ca, user=principal, password=_password_of(inventory, principal))


def open_session(inventory: Inventory, connect_timeout_s: float = 10.0) -> zenoh.Session:
    """A client session to the fleet's routers as ``inventory.principal``."""
    try:
        return open_client(
            inventory.endpoints,
            connect_timeout_s=connect_timeout_s,
            credentials=credentials(inventory, inventory.principal),
        )
    except RouterUnreachable as exc:
        if inventory.security.enabled:
            raise RouterUnreachable(
                f"{exc} (as principal {inventory.principal!r}: is its certificate or password "
                "accepted by the router?)"
            ) from None
        raise


def open_datagram_session(
    inventory: Inventory, connect_timeout_s: float = 10.0
) -> zenoh.Session | None:
    """The datagram session of stops (``fleet.wire.session.Datagram``) beside the session of
    ``open_session``, as the same principal: over UDP in an open fleet, over QUIC datagrams
    in a secure one (TLS 1.3 with the principal's certificate or password, under the same
    access control)."""
    return open_datagram(
        inventory.endpoints,
        inventory.datagram,
        connect_timeout_s,
        credentials(inventory, inventory.principal),
    )


def datagram_session(inventory: Inventory, beside: zenoh.Session | None = None) -> DatagramSession:
    """The datagram session of ``inventory``'s principal, to be opened (``DatagramSession``),
    beside the reliable session ``beside``."""
    twins = datagram_twins(inventory.endpoints, inventory.datagram)
    return DatagramSession(
        lambda: open_datagram_session(inventory), ", ".join(twins) or None, beside
    )


def router_config(
    inventory: Inventory, listen: list[str], connect: list[str] | None = None
) -> zenoh.Config:
    """A router for ``inventory``: its TLS and, when security is on, the access control and the
    payload limits generated from the inventory."""
    config = zenoh_config(
        "router",
        listen=listen,
        connect=connect or [],
        credentials=credentials(inventory, ROUTER_PRINCIPAL, router=True),
        datagram=inventory.datagram,
    )
    # Payload limits in every mode: an open fleet's heartbeat flood must not reach the agents.
    config.insert_json5("low_pass_filter", json.dumps(payload_limits(inventory)))
    overwrites = [*stop_qos_overwrite(KeySpace(inventory.fleet)), NEVER_WAIT_FOR_A_CONSUMER]
    config.insert_json5("qos/network", json.dumps(overwrites))
    if inventory.security.enabled:
        config.insert_json5("access_control", json.dumps(access_control(inventory)))
        max_message = str(inventory.security.max_payload_bytes * 2)
        config.insert_json5("transport/link/rx/max_message_size", max_message)
    return config
