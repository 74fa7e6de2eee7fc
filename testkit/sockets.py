"""Sockets as a test sees them: a viser WebSocket from a plain client, the non-loopback
peers of a process's sockets, and the bytes queued on its TCP connections (from /proc)."""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path
from typing import Any

import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect
from websockets.typing import Origin, Subprotocol


def ws(port: int, origin: str | None, cookie: str | None = None, query: str = "") -> Any:
    """A viser WebSocket from a plain client; the connection, or the refusal's HTTP status."""
    try:
        return connect(
            f"ws://127.0.0.1:{port}/{query}",
            origin=Origin(origin) if origin is not None else None,
            additional_headers={"Cookie": cookie} if cookie else None,
            subprotocols=[Subprotocol(f"viser-v{viser.__version__}")],
            open_timeout=5.0,
        )
    except InvalidStatus as refusal:
        return refusal.response.status_code


def loopback_only(pid: int) -> list[str]:
    """Remote addresses of ``pid``'s TCP and UDP sockets that are not loopback (or unset)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue  # closed meanwhile
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    outside = []
    for table in ("tcp", "tcp6", "udp", "udp6"):
        for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] not in inodes:
                continue
            raw = bytes.fromhex(fields[2].split(":")[0])
            # /proc prints each 32-bit word of the address in host (little-endian) order.
            words = [raw[i : i + 4][::-1] for i in range(0, len(raw), 4)]
            address = ipaddress.ip_address(b"".join(words))
            if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped:
                address = address.ipv4_mapped
            if not (address.is_loopback or address.is_unspecified):
                outside.append(f"{table} {address}")
    return outside


def queued_bytes(pid: int) -> int:
    """Bytes waiting on ``pid``'s TCP connections on this host: received and not read by it,
    plus sent towards it and not yet taken by its side (a peer's send queue). A process that
    stopped reading has a figure that grows to its buffers' size, then stays."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue  # closed meanwhile
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    rows = [line.split() for line in Path(f"/proc/{pid}/net/tcp").read_text().splitlines()[1:]]
    own = {row[1]: row for row in rows if row[9] in inodes}  # by local address:port
    total = 0
    for row in rows:
        tx_queue, rx_queue = (int(n, 16) for n in row[4].split(":"))
        if row[1] in own:
            total += rx_queue
        elif row[2] in own:  # the peer's end of one of its connections
            total += tx_queue
    return total
