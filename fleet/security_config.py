"""The inventory's ``[security]`` and ``[principals]`` sections, validated. Pure.

The security schema lives beside the inventory, below it (``fleet/inventory.py`` imports it and
it imports nothing of the product); ``fleet/security/`` holds the parts that run on an inventory
(access control, certificates, sessions) and sits above it.

A *principal* is an authenticated identity: the common name of a client certificate (``mtls``)
or a user name (``password``). Each has a *role* that decides what the router lets it do (see
``fleet/security/acl.py``). With ``mode = "none"`` (the loopback demo default) nothing is
authenticated: the principal in a key is whatever the client claims, and
docs/design/threat-model.md says so.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from msgspec import Struct

SecurityMode = Literal["none", "mtls", "password"]
Role = Literal[
    "agent", "coordinator", "operator", "observer", "maintainer", "simulator", "router", "ros2"
]
ROLES: tuple[Role, ...] = (
    "agent",
    "coordinator",
    "operator",
    "observer",
    "maintainer",
    "simulator",
    "router",
    "ros2",
)

DEFAULT_PRINCIPALS: dict[str, Role] = {
    "coordinator": "coordinator",
    "operator": "operator",
    "viewer": "observer",
    "maintainer": "maintainer",
    "sim": "simulator",
    "router": "router",
    "ros2": "ros2",
}
"""Principals every fleet has; ``[principals]`` adds to them (or changes their roles)."""

COMMANDERS: frozenset[Role] = frozenset({"coordinator", "operator", "maintainer"})
"""Roles that may command arms, take a lease over, reset and publish heartbeats."""

MAX_PAYLOAD_BYTES = 1 << 20
"""The router drops larger messages (``max_payload_bytes`` changes it); command, stop and reset
keys have the payload caps of ``fleet/wire/payloads.py`` (4 KiB)."""


class SecuritySection(Struct, frozen=True, forbid_unknown_fields=True):
    """``[security]``: how clients authenticate to the routers.

    ``certs``: a directory holding ``ca.pem`` and, per principal, ``<principal>.pem`` and
    ``<principal>.key`` (``fleet certs`` writes it), relative to the inventory file. ``passwords``
    (mode ``password``): a file of ``user:password`` lines; TLS with the router's certificate still
    encrypts the link."""

    mode: SecurityMode = "none"
    certs: str = "certs"
    passwords: str = "certs/passwords.txt"
    max_payload_bytes: int = MAX_PAYLOAD_BYTES


class Security(Struct, frozen=True):
    """The validated security settings, paths made absolute."""

    mode: SecurityMode = "none"
    certs: str = ""
    passwords: str = ""
    max_payload_bytes: int = MAX_PAYLOAD_BYTES

    @property
    def enabled(self) -> bool:
        """True unless ``mode = "none"``."""
        return self.mode != "none"

    def cert(self, principal: str) -> tuple[str, str]:
        """(certificate, private key) files of ``principal``."""
        base = Path(self.certs)
        return str(base / f"{principal}.pem"), str(base / f"{principal}.key")

    @property
    def ca(self) -> str:
        """The certificate authority every party trusts."""
        return str(Path(self.certs) / "ca.pem")


def resolve(section: SecuritySection, inventory_path: str) -> Security:
    """Paths relative to the inventory file; raises ValueError for a bad value."""
    if not 1024 <= section.max_payload_bytes <= 64 << 20:
        raise ValueError("max_payload_bytes must be within 1024..67108864")
    base = Path(inventory_path).resolve().parent
    return Security(
        mode=section.mode,
        certs=str((base / section.certs).resolve()),
        passwords=str((base / section.passwords).resolve()),
        max_payload_bytes=section.max_payload_bytes,
    )
