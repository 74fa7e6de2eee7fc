"""Per-robot state of the agent and the I/O batch its threads collect under the lock.

Every robot the agent serves is a *unit* with the same safety state (``ArmSafety``: latch,
lease, watchdog) and ordering: ``ArmSlot`` for a D1 arm (its tracker, seqs, acks and commands
in flight), ``DeviceSlot`` for a device of another kind (its driver, ``fleet/devices/driver``).
``Outbox`` holds the Zenoh puts and query replies computed under the agent's lock, performed
after it is released.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import zenoh

from edge_agent.acks import AckMatcher, ExecTimeouts
from edge_agent.commands import InFlight
from edge_agent.ordering import CommandOrder
from edge_agent.safety import ArmSafety
from edge_agent.tracker import ArmTracker
from fleet.d1.seq import SeqAllocator
from fleet.devices.driver import DeviceDriver
from fleet.wire import messages as m
from fleet.wire.stoppath import TwoPathPublisher


@dataclass
class ArmSlot:
    """One arm: tracker, safety state, seqs and the commands in flight."""

    tracker: ArmTracker
    seqs: SeqAllocator = field(default_factory=SeqAllocator)
    in_flight: dict[int, tuple[InFlight, zenoh.Query]] = field(default_factory=dict)
    order: CommandOrder = field(default_factory=CommandOrder)
    joints_seq: int = 0
    acks: AckMatcher = field(init=False)
    """Which written command each ack answers (by seq, or the oldest when the seq is unknown)."""

    def __post_init__(self) -> None:
        config = self.tracker.config
        exec_timeouts = ExecTimeouts(config.exec_ack_timeout_s, config.exec_ack_timeouts)
        self.acks = AckMatcher(config.recv_ack_timeout_s, exec_timeouts)

    @property
    def safety(self) -> ArmSafety:
        """The arm's stop latch, lease and watchdog (owned by its tracker's status)."""
        return self.tracker.safety

    @property
    def stop_action(self) -> str:
        """What a stop writes (the inventory's ``stop_action``)."""
        return self.tracker.config.stop_action


@dataclass
class DeviceSlot:
    """One device: its kind's key word, its driver, and the core's safety state for it."""

    kind: str
    driver: DeviceDriver
    safety: ArmSafety
    mount: str = ""
    order: CommandOrder = field(default_factory=CommandOrder)
    rejected: int = 0
    last_error: str | None = None

    @property
    def stop_action(self) -> str:
        """What a stop writes (the kind's action, or the inventory's choice)."""
        return self.driver.stop_action


Unit = ArmSlot | DeviceSlot


@dataclass
class Outbox:
    """I/O collected under the lock, performed after it is released."""

    puts: list[tuple[zenoh.Publisher | TwoPathPublisher, bytes | str]] = field(default_factory=list)
    replies: list[tuple[zenoh.Query, m.CommandReply]] = field(default_factory=list)
