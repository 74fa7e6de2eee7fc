"""Where a command queryable answers a query: a key Zenoh accepts, whatever key the query came on.

A queryable on ``<unit>/cmd/*`` (or ``coordinator/cmd/*``) receives every query whose key
matches it: ``cmd/alice``, but also ``cmd/bob.smith``, ``cmd/bob$*``, ``cmd/**``, 1000
characters, unicode. Zenoh refuses a reply on a key that does not intersect the query's
(``ZError``: "does not intersect with query"); a reply on ``cmd/unknown`` to ``cmd/bob.smith``
raised inside the agent's command thread, and its thread guard ended the agent. Every command
reply of the fleet takes its key from ``reply_key``: the unit's own concrete key when it
matches the query (the usual case, and one reply per unit to a wildcard query), else the
query's own key, which always matches itself.
"""

from __future__ import annotations

import zenoh

from fleet.wire import keys

UNNAMED = "unknown"
"""The principal chunk of a reply to a query whose key names no usable principal."""


def reply_key(query_key: str, commands_key: str) -> str:
    """The key to answer a query on ``query_key`` received by the queryable
    ``<commands_key>/*``: ``<commands_key>/<principal>``, or the query's own key when that one
    does not match the query."""
    chunk = query_key.rpartition("/")[2]
    own = f"{commands_key}/{chunk if keys.is_name(chunk) else UNNAMED}"
    if own == query_key or zenoh.KeyExpr(own).intersects(query_key):
        return own
    return query_key


def answer(query: zenoh.Query, commands_key: str, payload: bytes) -> None:
    """Reply ``payload`` (JSON) to ``query`` on ``reply_key`` and end the query."""
    key = reply_key(str(query.key_expr), commands_key)
    query.reply(key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)
    query.drop()  # type: ignore[no-untyped-call]
