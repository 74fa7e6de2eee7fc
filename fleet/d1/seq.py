"""Sequence numbers for commands, chosen by the caller as the D1 protocol requires.

The arm does not de-duplicate and answers with the seq of the command it acknowledges, so a seq
must be unique among the commands still waiting for their acknowledgments (the window). The arm
uses seq 10 for its own reports: we never send it.
"""

from __future__ import annotations

from fleet.d1.errors import ProtocolError
from fleet.d1.protocol import ARM_REPORT_SEQ

SEQ_FIRST = 1
SEQ_LAST = 65535


class SeqExhausted(ProtocolError):
    """Every usable seq is waiting for an acknowledgment: commands are not being answered."""


class SeqAllocator:
    """Hands out seqs in ``[first, last]``, wrapping, skipping 10 and any seq still in flight.

    Not thread-safe: the agent calls it under the lock that guards its pending-command table.
    """

    def __init__(self, first: int = SEQ_FIRST, last: int = SEQ_LAST) -> None:
        if first < 0 or last <= first:
            raise ValueError(f"bad seq range [{first}, {last}]")
        self._first = first
        self._last = last
        self._next = first
        self._in_flight: set[int] = set()

    @property
    def in_flight(self) -> frozenset[int]:
        """The seqs handed out and not yet released."""
        return frozenset(self._in_flight)

    def allocate(self) -> int:
        """The next free seq; it stays reserved until ``release``."""
        span = self._last - self._first + 1
        for _ in range(span):
            seq = self._next
            self._next = self._first if seq >= self._last else seq + 1
            if seq != ARM_REPORT_SEQ and seq not in self._in_flight:
                self._in_flight.add(seq)
                return seq
        raise SeqExhausted(f"all {len(self._in_flight)} seqs are awaiting acknowledgments")

    def release(self, seq: int) -> None:
        """The command with ``seq`` is finished (acknowledged or timed out)."""
        self._in_flight.discard(seq)
