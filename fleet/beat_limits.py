"""Heartbeats bounded before they are parsed: a size and a rate per principal.

Anyone allowed to beat (in open mode: anyone) could flood ``heartbeat/*``: 4 MB beats raised an
agent's stop -> ack from 2-7 ms to 63-376 ms. A beat carries at most one repeated stop per unit
of the fleet and one for the whole fleet, so its size is bounded by the inventory
(``max_heartbeat_bytes``): the router drops larger ones (``fleet.security.acl.payload_limits``,
in every security mode) and the agent checks the length again before it copies or decodes
anything. ``BeatGate`` then admits at most ``BEATS_PER_S`` beats per principal (a burst of as
many), before decoding: one principal's flood costs a counter, not a parse.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable

STOP_BYTES = 4096
"""The JSON of one repeated StopRequest: its names (128 chars each) and reason (1024 chars) with
room for escapes."""
BEATS_PER_S = 200.0
"""Beats admitted per principal and second: one principal may run several commanders (the
coordinator, a player, a mirror, CLIs) at 10-20 Hz each."""
MAX_PRINCIPALS = 256
"""Principals whose rate is tracked at once (the oldest is forgotten: it starts afresh)."""


def max_heartbeat_bytes(units: int) -> int:
    """The largest heartbeat a fleet of ``units`` arms and devices sends (every unit latched,
    and the fleet)."""
    return STOP_BYTES * (units + 2)


class BeatGate:
    """A token bucket per principal (``BEATS_PER_S``, burst as many); bounded table."""

    def __init__(
        self, rate_per_s: float = BEATS_PER_S, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._rate = rate_per_s
        self._clock = clock
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # tokens, at

    def admit(self, principal: str) -> bool:
        """True when ``principal`` may have one more beat parsed now (caller serialises)."""
        now = self._clock()
        tokens, at = self._buckets.pop(principal, (self._rate, now))
        tokens = min(self._rate, tokens + (now - at) * self._rate)
        admitted = tokens >= 1.0
        self._buckets[principal] = (tokens - 1.0 if admitted else tokens, now)
        while len(self._buckets) > MAX_PRINCIPALS:
            self._buckets.popitem(last=False)
        return admitted
