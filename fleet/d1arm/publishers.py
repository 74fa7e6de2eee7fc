"""The arms' Zenoh publishers, declared on the agent core's session (the stop acks are the
core's: every kind's stop is acknowledged the same way).

QoS, and why:
- ``joints`` and ``raw/*``: congestion control DROP. They are latest-wins state at 10 Hz; a slow
  subscriber must never stall the relay of the next sample (the newest sample is what counts).
  ``raw/feedback`` is put only while a subscriber matches it (Zenoh's matching status): it is
  for debugging and recording, nobody reads it most of the time, and it doubled the puts of the
  hot path. ``raw/command`` is always put: it is rare, and a recorder that subscribed just
  before a command must see it (the agent learns of a new subscriber a moment after the
  router does).
- ``status`` and ``diag``: DROP, DATA_HIGH: both repeat (4 Hz, 1 Hz), so a lost sample is
  replaced within 0.25 s; BLOCK let one subscriber that stopped reading (a frozen viewer) stall
  the router for every other session (measured on the test bed: 5-10 s without joints).
- ``raw/command``: DROP too: it is put from the safety thread after a stop's DDS write; a
  recorder may miss a mirror while the link to the router is congested.
The matching callback runs on Zenoh's receive thread (``direct``): one Python thread per arm
was hundreds of threads in one agent; it only sets a flag.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import zenoh

from fleet.control import direct
from fleet.guard import ThreadGuard
from fleet.wire import keys
from fleet.wire.keys import KeySpace

JSON = zenoh.Encoding.APPLICATION_JSON


@dataclass
class ArmPublishers:
    """The publishers of one arm."""

    joints: zenoh.Publisher
    status: zenoh.Publisher
    diag: zenoh.Publisher
    raw_feedback: zenoh.Publisher
    raw_command: zenoh.Publisher
    raw_feedback_matched: bool = False

    def all(self) -> tuple[zenoh.Publisher, ...]:
        """Every publisher (for undeclaring)."""
        return (self.joints, self.status, self.diag, self.raw_feedback, self.raw_command)


class ArmOutlets:
    """Every served arm's publishers (``by_arm``) and ``raw/feedback``'s matching listeners."""

    def __init__(
        self, zenoh_side: tuple[zenoh.Session, KeySpace], arms: list[str], guard: ThreadGuard
    ) -> None:
        session, space = zenoh_side
        self.by_arm: dict[str, ArmPublishers] = {}
        self._matching: list[zenoh.MatchingListener[None]] = []
        for arm in arms:
            pubs = self.by_arm[arm] = _declare(session, space, arm)
            on_matching = guard.wrap(_matcher(pubs), "matching")
            self._matching.append(pubs.raw_feedback.declare_matching_listener(direct(on_matching)))

    def mirror(self, arm: str, text: str) -> None:
        """Publish a command string written to ``arm`` on ``raw/command``."""
        self.by_arm[arm].raw_command.put(text)

    def close(self) -> None:
        """Undeclare the listeners, then the publishers (idempotent)."""
        publishers = [p for pubs in self.by_arm.values() for p in pubs.all()]
        for entity in [*self._matching, *publishers]:
            entity.undeclare()
        self._matching.clear()
        self.by_arm.clear()


def _declare(session: zenoh.Session, space: KeySpace, arm: str) -> ArmPublishers:
    def pub(
        channel: str, congestion: zenoh.CongestionControl, priority: zenoh.Priority
    ) -> zenoh.Publisher:
        return session.declare_publisher(
            space.arm(arm, channel), encoding=JSON, congestion_control=congestion, priority=priority
        )

    drop = zenoh.CongestionControl.DROP
    data, high = zenoh.Priority.DATA, zenoh.Priority.DATA_HIGH
    return ArmPublishers(
        joints=pub(keys.JOINTS, drop, data),
        status=pub(keys.STATUS, drop, high),
        diag=pub(keys.DIAG, drop, data),
        raw_feedback=pub(keys.RAW_FEEDBACK, drop, data),
        raw_command=pub(keys.RAW_COMMAND, drop, data),
    )


def _matcher(pubs: ArmPublishers) -> Callable[[zenoh.MatchingStatus], None]:
    def on_matching(status: zenoh.MatchingStatus) -> None:
        pubs.raw_feedback_matched = status.matching

    return on_matching
