"""The agent's ``commands`` thread: key-space commands in, each to its unit's server.

Takes queries off the command inbox and hands each to the ``UnitServer`` of the robot it names
(``fleet/devices/unit.py``), the same way for every kind. Every server runs the same envelope checks
first (``fleet/devices/envelope.py``: the principal and its role, duplicates / out-of-order /
lifetime, the lease, the watchdog's watch of a coordinator's motion), then the kind's own checks and
its write under the robot's write lock, with the stop latch read at the moment of writing. Queries
the inbox could not queue are answered 4003 "busy" (``busy``, on the Zenoh thread: a reply only).
"""

from __future__ import annotations

import threading
import time

from edge_agent.inbox import CommandInbox
from fleet.devices.unit import IncomingQuery, UnitServer


class CommandService:
    """Serves ``<kind>/<unit>/cmd`` for every robot of the agent."""

    def __init__(
        self,
        servers: dict[str, UnitServer],
        inbox: CommandInbox,
        stopping: threading.Event,
    ) -> None:
        self._servers = servers
        self._inbox = inbox
        self._stopping = stopping

    def run(self) -> None:
        """The ``commands`` thread: serve queries until the agent stops."""
        while not self._stopping.is_set():
            item = self._inbox.take()
            if item is None:
                self._inbox.wake.wait(0.2)
                continue
            self._handle(item)

    def _handle(self, item: IncomingQuery) -> None:
        self._servers[item.arm].serve(item, time.monotonic())

    def busy(self, item: IncomingQuery) -> None:
        """Answer a query the inbox could not queue (called on the Zenoh thread). While the
        agent starts, its queryables are declared before its servers exist: such a query is
        dropped unanswered (the caller sees no agent answer, as before the agent came)."""
        server = self._servers.get(item.arm)
        if server is None:
            item.query.drop()
            return
        why = f"{item.arm!r}: the agent is busy (its command queue is full); retry later"
        server.busy(item, why)
