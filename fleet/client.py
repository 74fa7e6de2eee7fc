"""A thin client over the public key space: what the CLI uses, and what any Zenoh client can do.

Nothing here is private to d1-fleet: every call is a query or a subscription on documented keys.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

import msgspec
import zenoh

from fleet.inventory import Inventory
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, ErrorInfo, encode
from fleet.wire.session import open_client

JSON = zenoh.Encoding.APPLICATION_JSON
REPLY_MARGIN_S = 2.0
"""A command's query waits this much longer than the command's own timeout."""


def _no_reply(arm: str, why: str) -> m.CommandReply:
    return m.CommandReply(
        ok=False,
        arm=arm,
        seq=None,
        received=False,
        executed=None,
        reached=None,
        latency_ms=0.0,
        error=ErrorInfo(int(ErrorCode.NOT_REGISTERED), why),
    )


class FleetClient:
    """A Zenoh session on the fleet's key space. A context manager."""

    def __init__(self, inventory: Inventory, session: zenoh.Session | None = None) -> None:
        self.inventory = inventory
        self.keys = keys.KeySpace(inventory.fleet)
        self._own_session = session is None
        self.session = session if session is not None else open_client(inventory.endpoints)

    # ------------------------------------------------------------------ commands

    def command(self, arm: str, command: m.ArmCommand) -> m.CommandReply:
        """Send ``command`` to ``arm``'s agent and wait for its reply."""
        self.inventory.arm(arm)  # unknown arm: InventoryError with the known ones
        timeout = (command.timeout_s if command.wait_reached else 3.0) + REPLY_MARGIN_S
        replies = self.session.get(
            self.keys.arm(arm, keys.CMD), payload=encode(command), encoding=JSON, timeout=timeout
        )
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                return m.reply_decoder.decode(reply.ok.payload.to_bytes())
            except msgspec.DecodeError as exc:
                return _no_reply(arm, f"arm {arm!r}: unreadable reply from its agent: {exc}")
        return _no_reply(
            arm,
            f"arm {arm!r}: no reply from its agent within {timeout:g} s "
            f"(no token on {self.keys.arm(arm, keys.AGENT)}?); is its edge-agent running?",
        )

    # ------------------------------------------------------------------ state

    def agents_alive(self) -> set[str]:
        """Arms whose agent liveliness token is present now."""
        alive = set()
        for reply in self.session.liveliness().get(self.keys.all_arms(keys.AGENT), timeout=1.0):
            if reply.ok is not None:
                alive.add(self.keys.parse_arm_key(str(reply.ok.key_expr)).arm)
        return alive

    def snapshot(
        self, arms: Iterable[str] | None = None, wait_s: float = 1.5
    ) -> dict[str, tuple[m.ArmStatus | None, m.Joints | None]]:
        """The latest status and joints of each arm, collected for up to ``wait_s`` seconds."""
        wanted = list(arms) if arms is not None else list(self.inventory.arms)
        statuses: dict[str, m.ArmStatus] = {}
        joints: dict[str, m.Joints] = {}
        done = threading.Event()
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            try:
                key = self.keys.parse_arm_key(str(sample.key_expr))
                data = sample.payload.to_bytes()
                with lock:
                    if key.channel == keys.STATUS:
                        statuses[key.arm] = m.status_decoder.decode(data)
                    elif key.channel == keys.JOINTS:
                        joints[key.arm] = m.joints_decoder.decode(data)
                    if all(a in statuses and a in joints for a in wanted):
                        done.set()
            except (keys.KeyError_, msgspec.DecodeError):
                return  # someone else's key or a foreign payload: not ours to report

        subs = [
            self.session.declare_subscriber(self.keys.all_arms(channel), on_sample)
            for channel in (keys.STATUS, keys.JOINTS)
        ]
        done.wait(wait_s)
        for sub in subs:
            sub.undeclare()
        with lock:
            return {a: (statuses.get(a), joints.get(a)) for a in wanted}

    def close(self) -> None:
        """Close the session if this client opened it (idempotent)."""
        if self._own_session and not self.session.is_closed():
            self.session.close()

    def __enter__(self) -> FleetClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
