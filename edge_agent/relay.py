"""The agent's Zenoh side: per-arm publishers, liveliness tokens and command queryables.

Publisher QoS, and why:
- ``joints`` and ``raw/*``: congestion control DROP. They are latest-wins state at 10 Hz; a slow
  subscriber must never stall the relay of the next sample (the newest sample is what counts).
- ``status`` and ``diag``: BLOCK, DATA_HIGH: rare and small, and a missed link change matters.
- ``estop/ack``: BLOCK, REAL_TIME: a stop's acknowledgment must arrive, and first.
- command replies go back on the query itself.
Queryable callbacks run on Zenoh threads: they only put the query on a queue (never block there).
"""

from __future__ import annotations

import queue
from dataclasses import dataclass

import zenoh

from fleet.wire import keys
from fleet.wire.session import open_client

JSON = zenoh.Encoding.APPLICATION_JSON

COMMAND_QUEUE_DEPTH = 256


@dataclass
class ArmPublishers:
    """The publishers of one arm."""

    joints: zenoh.Publisher
    status: zenoh.Publisher
    diag: zenoh.Publisher
    raw_feedback: zenoh.Publisher
    raw_command: zenoh.Publisher
    stop_ack: zenoh.Publisher

    def all(self) -> tuple[zenoh.Publisher, ...]:
        """Every publisher (for undeclaring)."""
        return (
            self.joints,
            self.status,
            self.diag,
            self.raw_feedback,
            self.raw_command,
            self.stop_ack,
        )


@dataclass(frozen=True)
class SafetyEvent:
    """A stop, reset or heartbeat sample, handed from a Zenoh thread to the safety thread.
    ``arm`` is None for fleet-wide keys."""

    channel: str
    arm: str | None
    payload: bytes


@dataclass(frozen=True)
class IncomingQuery:
    """A command query handed from a Zenoh thread to the agent's command thread."""

    arm: str
    query: zenoh.Query
    payload: bytes


class ZenohRelay:
    """Declares everything an agent needs on the key space, for the arms it serves."""

    def __init__(self, fleet: str, arm_ids: list[str], endpoints: list[str]) -> None:
        self.keys = keys.KeySpace(fleet)
        self.session = open_client(endpoints)
        self.commands: queue.Queue[IncomingQuery] = queue.Queue(maxsize=COMMAND_QUEUE_DEPTH)
        self.dropped_queries = 0
        # Stops must never be dropped: an unbounded queue, drained by a thread that does
        # nothing else. Heartbeats share it (10 Hz, tiny) so a stop they repeat is in order.
        self.safety: queue.SimpleQueue[SafetyEvent] = queue.SimpleQueue()
        self.publishers: dict[str, ArmPublishers] = {}
        self._tokens: list[zenoh.LivelinessToken] = []
        self._queryables: list[zenoh.Queryable[None]] = []
        self._subscribers: list[zenoh.Subscriber[None]] = [
            self.session.declare_subscriber(self.keys.estop, self._on_safety(keys.ESTOP, None)),
            self.session.declare_subscriber(self.keys.reset, self._on_safety(keys.RESET, None)),
            self.session.declare_subscriber(
                self.keys.heartbeat, self._on_safety(keys.HEARTBEAT, None)
            ),
        ]
        for arm in arm_ids:
            for channel in (keys.ESTOP, keys.RESET):
                self._subscribers.append(
                    self.session.declare_subscriber(
                        self.keys.arm(arm, channel), self._on_safety(channel, arm)
                    )
                )
        for arm in arm_ids:
            self.publishers[arm] = self._declare_publishers(arm)
            self._queryables.append(
                self.session.declare_queryable(self.keys.arm(arm, keys.CMD), self._on_query(arm))
            )
        # Tokens last: an agent is announced only once it can serve its arms.
        for arm in arm_ids:
            self._tokens.append(
                self.session.liveliness().declare_token(self.keys.arm(arm, keys.AGENT))
            )

    def _declare_publishers(self, arm: str) -> ArmPublishers:
        def pub(
            channel: str, congestion: zenoh.CongestionControl, priority: zenoh.Priority
        ) -> zenoh.Publisher:
            return self.session.declare_publisher(
                self.keys.arm(arm, channel),
                encoding=JSON,
                congestion_control=congestion,
                priority=priority,
            )

        drop, block = zenoh.CongestionControl.DROP, zenoh.CongestionControl.BLOCK
        data, high = zenoh.Priority.DATA, zenoh.Priority.DATA_HIGH
        return ArmPublishers(
            joints=pub(keys.JOINTS, drop, data),
            status=pub(keys.STATUS, block, high),
            diag=pub(keys.DIAG, block, data),
            raw_feedback=pub(keys.RAW_FEEDBACK, drop, data),
            raw_command=pub(keys.RAW_COMMAND, block, data),
            stop_ack=pub(keys.ESTOP_ACK, block, zenoh.Priority.REAL_TIME),
        )

    def _on_safety(self, channel: str, arm: str | None):  # type: ignore[no-untyped-def]
        def handler(sample: zenoh.Sample) -> None:
            self.safety.put(SafetyEvent(channel, arm, sample.payload.to_bytes()))

        return handler

    def _on_query(self, arm: str):  # type: ignore[no-untyped-def]
        def handler(query: zenoh.Query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            try:
                self.commands.put_nowait(IncomingQuery(arm, query, payload))
            except queue.Full:
                # Counted and answered nowhere: the caller's get() times out. This only happens
                # when 256 commands are queued, i.e. the agent is wedged.
                self.dropped_queries += 1

        return handler

    def close(self) -> None:
        """Undeclare tokens first (the fleet sees the agent leave), then close the session."""
        for token in self._tokens:
            token.undeclare()
        self._tokens.clear()
        for queryable in self._queryables:
            queryable.undeclare()
        self._queryables.clear()
        for pubs in self.publishers.values():
            for publisher in (
                pubs.joints,
                pubs.status,
                pubs.diag,
                pubs.raw_feedback,
                pubs.raw_command,
            ):
                publisher.undeclare()
        self.publishers.clear()
        self.session.close()
