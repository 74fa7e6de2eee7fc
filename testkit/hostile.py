"""Shared pieces of the hostile-input suite: the poison payloads a security review used, and
the check every attack ends with (the fleet still stops and still serves).

Every payload here was reproduced against real processes: each one, before the fix, killed a
thread of an agent or of the coordinator, or crashed a process.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import msgspec
import zenoh

from fleet.client import FleetClient
from fleet.wire import messages as m
from testkit.harness import FleetHarness, wait_until

NEST = 1000
"""msgspec raises RecursionError (not DecodeError) for JSON nested this deep."""


def nested(tail: bytes = b"") -> bytes:
    """A JSON object whose unknown field ``junk``, nested NEST deep (~2 KB), comes first: msgspec
    skips it (recursively) before it finds the fields after it, a tagged union's ``op`` too."""
    return b'{"junk":' + b"[" * NEST + b"]" * NEST + (b"," + tail if tail else b"") + b"}"


STOP_HEAD = b'"stamp_ns":1,"source":"x","stop_id":"y"'
POISONS: dict[str, bytes] = {
    "nested": nested(STOP_HEAD),
    "bad-utf8": b'{"stamp_ns":1,"source":"\xff\xfe","stop_id":"y"}',
    "1MiB": b'{"stamp_ns":1,"source":"x","stop_id":"' + b"z" * (1 << 20) + b'"}',
    "not-json": b"\x00\x01 not json",
    "empty": b"",
}
"""Payloads that are not valid anything, in the shapes that broke the landed code."""
ROUTER_DROPS = frozenset({"1MiB"})
"""Poisons the router drops before any agent sees them: over the 4 KiB limit it puts on every
command, stop and reset key (and on heartbeats, by the fleet's size), in every security mode.
A stop is never legitimately that large; one that is stops nothing, and nothing else happens."""

STOP_ACK_BOUND_MS = 500.0
"""A stop is acted on in 1-2 ms on a quiet host; 500 ms leaves room for a loaded 2-core CI host
and is still far below the 3-5 s a flood used to cause."""


def put(client: FleetClient, key: str, payload: bytes, *, every_one: bool = False) -> None:
    """One put from the test's own (hostile) Zenoh session. ``every_one`` puts it with
    congestion control BLOCK: Zenoh's default, DROP, may drop the puts that follow a 1 MiB one
    on the sender's own queue, and a test that counts what arrived must send all of it."""
    if every_one:
        client.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
    else:
        client.session.put(key, payload)


def alive(harness: FleetHarness) -> dict[str, int | None]:
    """Exit code of every process the harness started (None: running)."""
    return {name: process.poll() for name, process in harness.processes.items()}


def statuses(client: FleetClient, arms: list[str]) -> dict[str, m.ArmStatus | None]:
    """The newest status of each arm."""
    return {arm: status for arm, (status, _joints) in client.snapshot(arms, wait_s=1.0).items()}


def wait_reset(client: FleetClient, arms: list[str], timeout_s: float = 10.0) -> None:
    """Reset every arm and wait until none reports a latched stop."""

    def clear() -> bool:
        client.reset()
        return all(s is not None and not s.estopped for s in statuses(client, arms).values())

    wait_until(clear, timeout_s)


def assert_fleet_stops_and_serves(harness: FleetHarness, client: FleetClient) -> float:
    """What every attack ends with: every process is still up; a fleet stop is acknowledged
    by every arm within STOP_ACK_BOUND_MS and each arm is seen still; after a reset, a valid
    command works. Returns the slowest ack in ms."""
    arms = list(harness.inventory.arms)
    assert all(code is None for code in alive(harness).values()), alive(harness)
    wait_reset(client, arms)
    request = client.stop_request(reason="is the stop still working?", source="hostile-suite")
    acks = client.estop(timeout_s=5.0, request=request)
    missing = [arm for arm, ack in acks.items() if ack is None or ack.still_ns is None]
    assert not missing, f"no ack (or never still) from {missing}: {acks}"
    slowest = max((a.received_ns - request.stamp_ns) / 1e6 for a in acks.values() if a)
    assert slowest <= STOP_ACK_BOUND_MS, f"the stop was acted on after {slowest:.0f} ms"
    wait_reset(client, arms)
    for arm in arms:
        target = 3.0 if time.monotonic() % 2 < 1 else -3.0
        command = m.MoveJoint(joint=0, angle_deg=target, wait_reached=True, timeout_s=8.0)
        reply = client.command(arm, command)
        assert reply.ok, f"{arm}: {reply.error}"
    assert all(code is None for code in alive(harness).values()), alive(harness)
    return slowest


def rss_mb(pid: int) -> float:
    """Resident memory of a process, MB."""
    text = Path(f"/proc/{pid}/status").read_text()
    found = re.search(r"VmRSS:\s+(\d+) kB", text)
    return int(found.group(1)) / 1024 if found else 0.0


def threads_of(pid: int) -> int:
    """OS threads of a process."""
    return len(os.listdir(f"/proc/{pid}/task"))


def latest(client: FleetClient, key: str, wait_s: float = 1.5) -> bytes | None:
    """The newest payload seen on ``key`` within ``wait_s``."""
    got: list[bytes] = []
    sub = client.session.declare_subscriber(key, lambda s: got.append(s.payload.to_bytes()))
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not got:
        time.sleep(0.05)
    time.sleep(0.1)
    sub.undeclare()
    return got[-1] if got else None


def decode(kind: type, data: bytes | None) -> object:
    """Decode a trusted payload in a test (our own processes published it)."""
    assert data is not None
    return msgspec.json.decode(data, type=kind)


HOSTILE_CHUNKS: dict[str, str] = {
    "dots": "bob.smith",
    "star": "*",
    "double-star": "**",
    "dollar-star": "bob$*",
    "long": "p" * 1000,
    "unicode": "bób-ñ",
    "space": "bob smith",
}
"""Last chunks of a command key that name no usable principal, though Zenoh accepts each
(``keys.is_name`` refuses them). A reply on ``.../cmd/unknown`` does not match most of them:
before the fix each such query made the agent's reply raise, and the agent exit."""
INVALID_KEYS = (
    "{unit}//bob",
    "{unit}/cmd//bob",
    "{unit}/cmd/bob/",
    "{unit}/cmd/$*",
    "{unit}/cmd/b#b",
)
"""Key expressions Zenoh itself refuses (empty chunks, a trailing slash, a lone ``$*``, ``#``):
never sent."""
