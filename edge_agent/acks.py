"""Which written command an arm's acknowledgment answers. Pure, with an injected clock.

The service interface reads two ways: its table says the receive/execute acks' seq is "caller
generates" (the arm echoes the command's seq), but every ack example carries ``"seq":10``, the
seq of the arm's own reports. Both readings are handled:
- an ack whose seq is one we wrote and that still awaits this kind of ack answers that command;
- an ack whose seq is one we wrote recently but that awaits no such ack any more (it came after
  the timeout, or twice) is *late*: ignored and counted (``diag.acks_ignored``); crediting it to
  another command would hide that command's own missing ack;
- any other ack (seq 10, or a seq we never wrote) answers the oldest written command still
  awaiting this kind of ack: it is *unmatched*, and the agent counts it (``diag.acks_unmatched``);
  with no command awaiting one it is ignored and counted too.

Attributing by age needs the arm to answer each kind of ack in the order it received the
commands, to answer each command at most once per kind, and to send no execute ack for a command
it refused (``recv_status`` 0). DDS keeps the order of one writer's samples (the agent writes an
arm's commands through one writer, one at a time). A lost ack shifts the attribution by one until
the oldest entry expires: entries live as long as the arm's ack timeout, after which the command
has failed (3104) anyway.

Every command written is recorded here, including those whose acks nobody awaits (stops, holds,
force limits): with an arm that answers seq 10, the ack of a stop must be consumed by the stop,
not credited to a command written after it.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Literal

from fleet.d1 import protocol as p

Attribution = Literal["seq", "oldest", "late", "none"]
"""How an ack was attributed: by its own seq; to the oldest command awaiting one (its seq named
none); not at all, as a late or repeated ack of a command we wrote; not at all, no command
awaiting one."""

MAX_AWAITING = 256
"""Written commands remembered per ack kind; more only happens when an arm stops answering
(entries also expire after the ack timeout), and then the oldest are forgotten first."""


class AckMatcher:
    """The written commands of one arm still awaiting their receive and execute acks."""

    def __init__(self, recv_timeout_s: float, exec_timeout_s: float) -> None:
        self._timeouts = {p.ReceiveAck: recv_timeout_s, p.ExecuteAck: exec_timeout_s}
        # seq -> monotonic time written, oldest first, one table per ack kind
        self._awaiting: dict[type, OrderedDict[int, float]] = {
            p.ReceiveAck: OrderedDict(),
            p.ExecuteAck: OrderedDict(),
        }
        self._recent: OrderedDict[int, None] = OrderedDict()  # seqs written lately, oldest first

    def written(self, seq: int, now: float) -> None:
        """Record a command written with ``seq`` at ``now`` (call before the DDS write: its
        ack may come back before the write returns)."""
        for table in self._awaiting.values():
            table.pop(seq, None)
            table[seq] = now
            while len(table) > MAX_AWAITING:
                table.popitem(last=False)
        self._recent.pop(seq, None)
        self._recent[seq] = None
        while len(self._recent) > MAX_AWAITING:
            self._recent.popitem(last=False)

    def answered(
        self, ack: p.ReceiveAck | p.ExecuteAck, now: float
    ) -> tuple[int | None, Attribution]:
        """The seq of the command ``ack`` answers (None: none) and how it was attributed."""
        kind = type(ack)
        table = self._awaiting[kind]
        self._expire(table, self._timeouts[kind], now)
        how: Attribution
        if ack.seq in table:
            seq, how = ack.seq, "seq"
            del table[seq]
        elif ack.seq in self._recent:
            return None, "late"
        elif table:
            seq, _written_s = table.popitem(last=False)
            how = "oldest"
        else:
            return None, "none"
        if isinstance(ack, p.ReceiveAck) and not ack.ok:
            # A command the arm could not take is not executed: no execute ack will follow.
            self._awaiting[p.ExecuteAck].pop(seq, None)
        return seq, how

    @staticmethod
    def _expire(table: OrderedDict[int, float], timeout_s: float, now: float) -> None:
        """Forget commands whose ack is overdue: they have failed with 3104 already, and one
        lost ack must not shift the attribution of every later ack for ever."""
        while table:
            seq, written_s = next(iter(table.items()))
            if now - written_s <= timeout_s:
                return
            del table[seq]

    def awaiting(self) -> tuple[int, int]:
        """How many written commands await a receive ack and an execute ack (for tests)."""
        return len(self._awaiting[p.ReceiveAck]), len(self._awaiting[p.ExecuteAck])
