"""The two paths of a stop (issue 24): every stop, its repeats, its acks and the heartbeats that
repeat latched stops are put twice on the same key, once reliable (congestion control BLOCK,
over the session's TCP link) and once best-effort and express (over its UDP link, when the
session has one: ``fleet.wire.session.Datagram``). Zenoh picks the link by the message's
reliability, so the best-effort copy never queues behind a TCP retransmission; the receivers
already de-duplicate (agents by ``stop_id``, acks and heartbeats are latest-wins).

Without a datagram link (TLS endpoints, ``datagram = false``) the best-effort copy goes the
reliable link's way: a duplicate, harmless and cheap.
"""

from __future__ import annotations

import zenoh

JSON = zenoh.Encoding.APPLICATION_JSON

RELIABLE_QOS: dict[str, object] = {
    "congestion_control": zenoh.CongestionControl.BLOCK,
    "priority": zenoh.Priority.REAL_TIME,
}
"""Stops and resets on the reliable path: never dropped under congestion, sent first."""

DATAGRAM_QOS: dict[str, object] = {
    "congestion_control": zenoh.CongestionControl.DROP,
    "priority": zenoh.Priority.REAL_TIME,
    "express": True,
    "reliability": zenoh.Reliability.BEST_EFFORT,
}
"""The datagram copy: never waits (DROP: another copy follows within 10-100 ms), not batched."""

BURST_INTERVAL_S = 0.01
"""A new stop's datagram copies go every 10 ms for its first ``BURST_S``: at 51 % loss per
path, 6 copies reach an agent with 98.6 % within 50 ms, independent of TCP's timers."""
BURST_S = 0.05


class TwoPathPublisher:
    """One key, two publishers: ``put`` sends the payload on both paths (datagram first: it is
    the one that cannot be held up). A context manager; ``undeclare`` is idempotent."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self.datagram = session.declare_publisher(key, encoding=JSON, **DATAGRAM_QOS)  # type: ignore[arg-type]
        self.reliable = session.declare_publisher(key, encoding=JSON, **RELIABLE_QOS)  # type: ignore[arg-type]
        self._undeclared = False

    def put(self, payload: bytes | str) -> None:
        """Both paths."""
        self.datagram.put(payload)
        self.reliable.put(payload)

    def put_datagram(self, payload: bytes | str) -> None:
        """The datagram path only (the fast repeats of a stop's first 50 ms)."""
        self.datagram.put(payload)

    def undeclare(self) -> None:
        """Undeclare both publishers (idempotent)."""
        if not self._undeclared:
            self._undeclared = True
            self.datagram.undeclare()
            self.reliable.undeclare()

    def __enter__(self) -> TwoPathPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.undeclare()
