"""One D1 arm's state in the agent: its tracker, seqs, acks and the commands in flight, and
the bookkeeping done on them under the agent's lock (finished commands, acks). The core's
safety state (``Unit``) is its tracker's latch, lease and watchdog.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import msgspec
import zenoh

from fleet.d1 import protocol as p
from fleet.d1.seq import SeqAllocator
from fleet.d1arm.acks import AckMatcher, ExecTimeouts
from fleet.d1arm.commands import InFlight
from fleet.d1arm.tracker import ArmTracker
from fleet.devices.ordering import CommandOrder
from fleet.devices.safety import ArmSafety
from fleet.devices.unit import Outbox
from fleet.wire.messages import ErrorCode


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

    def collect_finished(self, now: float, out: Outbox) -> None:
        """Move finished commands from the in-flight table to ``out`` (caller holds the
        lock)."""
        finished: dict[int, tuple[InFlight, zenoh.Query]] = {}
        for seq, (flight, query) in list(self.in_flight.items()):
            if flight.done:
                del self.in_flight[seq]
                self.seqs.release(seq)
                finished[id(flight)] = (flight, query)
        for flight, query in finished.values():
            reply = flight.reply(now)
            if reply.error is not None:
                self.tracker.last_error = reply.error.message
                if reply.error.code == ErrorCode.TIMEOUT:  # an ack, not a target, is late
                    self.tracker.ack_timeouts += 1
            out.replies.append((query, reply))

    def cancel_in_flight(self, now: float, why: str, out: Outbox) -> None:
        """Fail every command in flight (caller holds the lock)."""
        for flight, _query in self.in_flight.values():
            flight.fail(ErrorCode.REJECTED, why)
        self.collect_finished(now, out)

    def on_ack(self, ack: p.ReceiveAck | p.ExecuteAck, now: float) -> None:
        """Credit ``ack`` to the written command it answers (caller holds the lock): by its
        seq, or, when it carries seq 10 (an arm answering as the spec's examples do), to the
        oldest command awaiting this kind of ack (``acks.py``), counted as unmatched; any other
        seq is counted as foreign and credited to nothing."""
        tracker = self.tracker
        seq, how = self.acks.answered(ack, now)
        if how == "foreign":
            tracker.acks_foreign += 1
            tracker.last_error = (
                f"{type(ack).__name__} with seq {ack.seq} ignored: neither a command of ours "
                f"nor the arm's seq {p.ARM_REPORT_SEQ} (another client commanding the arm?)"
            )
            return
        if seq is None:
            tracker.acks_ignored += 1
            why = "a late or repeated ack" if how == "late" else "no command written awaits one"
            tracker.last_error = f"{type(ack).__name__} with seq {ack.seq} ignored: {why}"
            return
        if how == "oldest":
            tracker.acks_unmatched += 1
            ack = msgspec.structs.replace(ack, seq=seq)
        entry = self.in_flight.get(seq)
        if entry is not None:  # else a stop, hold or force limit: nobody awaits its acks
            entry[0].on_ack(ack)
