"""Which written command an arm's acknowledgment answers. Pure, with an injected clock.

The service interface reads two ways: its table says the receive/execute acks' seq is "caller
generates" (the arm echoes the command's seq), but every ack example carries ``"seq":10``, the
seq of the arm's own reports. Both readings are handled:
- an ack whose seq is one we wrote and that still awaits this kind of ack answers that command;
- an ack whose seq is one we wrote recently but that awaits no such ack any more (it came after
  the timeout, or twice) is *late*: ignored and counted (``diag.acks_ignored``); crediting it to
  another command would hide that command's own missing ack;
- an ack with seq 10 (the arm's own seq: we never write it) answers the oldest written command
  still awaiting this kind of ack: it is *unmatched*, and the agent counts it
  (``diag.acks_unmatched``); with no command awaiting one it is ignored and counted too;
- an ack with any other seq (neither one we wrote lately nor 10: another client's command on the
  arm's topic, or garbage) is *foreign*: counted (``diag.acks_foreign``), never credited (it
  would complete our oldest command with another command's result).

Attributing by age needs the arm to answer each kind of ack in the order it received the
commands, to answer each command at most once per kind, and to send no execute ack for a command
it refused (``recv_status`` 0). DDS keeps the order of one writer's samples (the agent writes an
arm's commands through one writer, one at a time). A lost ack shifts the attribution by one until
the oldest entry expires: entries live as long as the arm's ack timeout, after which the command
has failed (3104) anyway. The execute-ack timeout is per D1 command (``ExecTimeouts``): "executed"
may mean "motion finished" (a return to zero, a long move), which takes longer than an enable.

Every command written is recorded here, including those whose acks nobody awaits (stops, holds,
force limits): with an arm that answers seq 10, the ack of a stop must be consumed by the stop,
not credited to a command written after it.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from typing import Literal

from fleet.d1 import protocol as p

Attribution = Literal["seq", "oldest", "late", "foreign", "none"]
"""How an ack was attributed: by its own seq; to the oldest command awaiting one (seq 10); not
at all, as a late or repeated ack of a command we wrote; not at all, a seq neither ours nor 10;
not at all, no command awaiting one."""

EXEC_ACK_OPS: dict[type, str] = {
    p.SetJointAngle: "move_joint",
    p.SetAllAngles: "move_joints",
    p.SetJointTorque: "torque",
    p.SetAllTorque: "torque",
    p.SetPower: "power",
    p.ReturnToZero: "zero",
}
"""The name of each D1 command in the execute-ack timeout table (the key-space op that sends
it; a hold and a stop are ``move_joints``)."""

DEFAULT_EXEC_ACK_TIMEOUTS_S: dict[str, float] = {
    "move_joint": 5.0,
    "move_joints": 5.0,
    "zero": 10.0,
}
"""Built-in per-op execute-ack timeouts, in case "executed" means "motion finished": a move
across a joint's whole range (270 deg) at the large smoothing's ~90 deg/s takes about 3 s plus
the lag; a return to zero is up to six such moves, which the arm may make one after another.
An op not named here waits ``exec_ack_timeout_s``, which is also the least any op waits."""


class ExecTimeouts:
    """The execute-ack timeout of each D1 command of one arm: the arm's own table
    (``exec_ack_timeouts``), else the built-in one, and never less than ``exec_ack_timeout_s``."""

    def __init__(self, default_s: float, table: Mapping[str, float] | None = None) -> None:
        self.default_s = default_s
        ops = set(EXEC_ACK_OPS.values())
        self._by_op = {op: max(DEFAULT_EXEC_ACK_TIMEOUTS_S.get(op, 0.0), default_s) for op in ops}
        self._by_op.update(table or {})

    def of(self, command: p.Command | None) -> float:
        """The execute-ack timeout of ``command`` (None: the arm's default)."""
        if command is None:
            return self.default_s
        return self._by_op.get(EXEC_ACK_OPS.get(type(command), ""), self.default_s)

    def longest(self, commands: tuple[p.Command, ...]) -> float:
        """The longest timeout of ``commands`` (a plan's deadline: all of them executed)."""
        return max((self.of(c) for c in commands), default=self.default_s)


MAX_AWAITING = 256
"""Written commands remembered per ack kind; more only happens when an arm stops answering
(entries also expire after the ack timeout), and then the oldest are forgotten first."""


class AckMatcher:
    """The written commands of one arm still awaiting their receive and execute acks."""

    def __init__(self, recv_timeout_s: float, exec_timeout_s: ExecTimeouts | float) -> None:
        """``exec_timeout_s``: the arm's per-op table, or its default (then the built-in table
        applies, never below it)."""
        self._recv_timeout_s = recv_timeout_s
        self.exec_timeouts = (
            exec_timeout_s
            if isinstance(exec_timeout_s, ExecTimeouts)
            else ExecTimeouts(exec_timeout_s)
        )
        # seq -> monotonic deadline of its ack, in write order, one table per ack kind
        self._awaiting: dict[type, OrderedDict[int, float]] = {
            p.ReceiveAck: OrderedDict(),
            p.ExecuteAck: OrderedDict(),
        }
        self._recent: OrderedDict[int, None] = OrderedDict()  # seqs written lately, oldest first

    def written(self, seq: int, now: float, command: p.Command | None = None) -> None:
        """Record ``command`` written with ``seq`` at ``now`` (call before the DDS write: its
        ack may come back before the write returns)."""
        deadlines = {
            p.ReceiveAck: now + self._recv_timeout_s,
            p.ExecuteAck: now + self.exec_timeouts.of(command),
        }
        for kind, table in self._awaiting.items():
            table.pop(seq, None)
            table[seq] = deadlines[kind]
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
        self._expire(table, now)
        how: Attribution
        if ack.seq in table:
            seq, how = ack.seq, "seq"
            del table[seq]
        elif ack.seq in self._recent:
            return None, "late"
        elif ack.seq != p.ARM_REPORT_SEQ:
            return None, "foreign"
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
    def _expire(table: OrderedDict[int, float], now: float) -> None:
        """Forget commands whose ack is overdue: they have failed with 3104 already, and one
        lost ack must not shift the attribution of every later ack for ever. (Deadlines differ
        per op, so the whole table is checked, not only its oldest entry.)"""
        for seq, deadline_s in list(table.items()):
            if now > deadline_s:
                del table[seq]

    def awaiting(self) -> tuple[int, int]:
        """How many written commands await a receive ack and an execute ack (for tests)."""
        return len(self._awaiting[p.ReceiveAck]), len(self._awaiting[p.ExecuteAck])
