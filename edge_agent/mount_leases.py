"""The leases of arms served by another agent that devices of this agent are mounted on.

An arm's lease covers the gripper mounted on it (``DeviceServer``): where one agent serves
both, it reads the arm's lease itself; where the arm has an agent of its own, this agent learns
the lease from the arm's status (``arm/<arm>/status``: ``owner``, ``lease_left_s``, 4 Hz and on
every change; only the arm's agent may publish there). A lease taken or released shows here
within one status (at most 0.25 s). The callback only decodes and stores the newest, under a
short lock; a status that does not decode is counted (``bad_payloads``) and ignored.
"""

from __future__ import annotations

import threading
import time

from edge_agent.inbox import InboxCounters
from fleet.devices.safety import Lease
from fleet.wire import payloads


class MountLeases:
    """The newest lease each watched arm's status reports (monotonic seconds)."""

    def __init__(self, counters: InboxCounters) -> None:
        self._counters = counters
        self._lock = threading.Lock()  # guards _leases and the counter
        self._leases: dict[str, Lease | None] = {}

    def on_status(self, arm: str, data: bytes) -> None:
        """A status sample of ``arm`` (Zenoh thread)."""
        now = time.monotonic()
        try:
            status = payloads.STATUS.decode(data)
        except payloads.PayloadError:
            with self._lock:
                self._counters.bad_payloads += 1
            return
        lease = None
        if status.owner is not None and status.lease_left_s is not None:
            since = now - (status.owned_s or 0.0)
            lease = Lease(status.owner, now + status.lease_left_s, since)
        with self._lock:
            self._leases[arm] = lease

    def holder(self, arm: str, now: float) -> Lease | None:
        """Who holds ``arm`` at ``now`` by its newest status (None: nobody, or not heard)."""
        with self._lock:
            lease = self._leases.get(arm)
        return lease if lease is not None and lease.expires_s > now else None
