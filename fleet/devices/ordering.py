"""Commands executed at most once, and never out of order for one owner. Pure.

Zenoh's reliability is hop by hop; a client may retry, a link may duplicate, and anyone who can
send a command can send it twice, or send an old one again. Every command the fleet's clients
send carries ``stamp_ns`` (the sender's clock, strictly increasing per client) and a lifetime:
- a command whose (principal, ``stamp_ns``) was already served on this arm is a duplicate or a
  replay: refused, never executed again;
- for one owner (``<principal>/<owner>``), a command older than the last one served on this
  arm arrived out of order (a stale target overtaken by a newer one): refused;
- past its lifetime it is refused before it gets here (``serving.py``).
Both tables are bounded: ``MAX_OWNERS`` owners and ``MAX_RECENT`` stamps per arm, the oldest
forgotten first (a replay older than that is past any lifetime anyway).
"""

from __future__ import annotations

from collections import OrderedDict

from fleet.wire.messages import OVERTAKEN

MAX_OWNERS = 1024
MAX_RECENT = 1024


class CommandOrder:
    """At-most-once and in-order bookkeeping of one arm's commands."""

    def __init__(self) -> None:
        self._last: OrderedDict[str, int] = OrderedDict()
        self._recent: OrderedDict[tuple[str, int], None] = OrderedDict()

    def refusal(self, principal: str, owner: str | None, stamp_ns: int | None) -> str | None:
        """Why this command must not run (None: it may)."""
        if stamp_ns is None:
            return None
        if (principal, stamp_ns) in self._recent:
            return f"a duplicate of a command already served (stamp_ns {stamp_ns}): not run twice"
        last = None if owner is None else self._last.get(owner)
        if last is not None and stamp_ns <= last:
            return (
                f"{OVERTAKEN}: older than the last command of {owner!r} "
                f"({(last - stamp_ns) / 1e6:.1f} ms): a stale target is never executed"
            )
        return None

    def record(self, principal: str, owner: str | None, stamp_ns: int | None) -> None:
        """The command was accepted."""
        if stamp_ns is None:
            return
        self._recent[(principal, stamp_ns)] = None
        while len(self._recent) > MAX_RECENT:
            self._recent.popitem(last=False)
        if owner is not None:
            self._last[owner] = stamp_ns
            self._last.move_to_end(owner)
            while len(self._last) > MAX_OWNERS:
                self._last.popitem(last=False)
