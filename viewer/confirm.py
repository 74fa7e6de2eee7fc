"""Two-step confirmations kept on the server (the fleet's reset, one arm's reset). Pure: the
clock is injected.

The reset dialog is a browser-side modal, and a browser can send any GUI event it likes. So the
server remembers, per browser connection, that it asked (``request``: a one-time nonce for one
target, expiring after ``window_s``); the confirm handler acts only if ``confirm`` finds that
very request, for that target, from that connection, unexpired, and not used before. A lone
"confirm" event does nothing, and a dialog for a1 cannot confirm a reset of the whole fleet.
"""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable

CONFIRM_WINDOW_S = 30.0
"""How long a reset dialog stays valid: long enough to read it and look at the cell, short
enough that a dialog left open is not a loaded reset."""
FLEET = "*"
"""The target of a fleet-wide confirmation (never an arm name: those match [A-Za-z0-9])."""


class Confirmations:
    """Pending confirmations, at most one per client (a new request replaces the old)."""

    def __init__(
        self, window_s: float = CONFIRM_WINDOW_S, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.window_s = window_s
        self._clock = clock
        self._lock = threading.Lock()  # guards _pending (viser callbacks run on a thread pool)
        self._pending: dict[int, tuple[str, float]] = {}

    def request(self, client_id: int, target: str = FLEET) -> str:
        """Step one for ``client_id`` about ``target`` (an arm, or FLEET): returns the nonce its
        confirm button must present."""
        nonce = f"{target}:{secrets.token_hex(8)}"
        now = self._clock()
        with self._lock:
            # Drop expired entries of other clients (closed tabs), so the dict stays small.
            self._pending = {c: p for c, p in self._pending.items() if p[1] > now}
            self._pending[client_id] = (nonce, now + self.window_s)
        return nonce

    def confirm(self, client_id: int, nonce: str, target: str = FLEET) -> bool:
        """Step two: True (once) if ``client_id`` has an unexpired request about ``target``
        with ``nonce``."""
        now = self._clock()
        with self._lock:
            pending = self._pending.get(client_id)
            if pending is None or not nonce.startswith(f"{target}:"):
                return False
            if not secrets.compare_digest(pending[0].encode(), nonce.encode()):
                return False
            del self._pending[client_id]
            return now < pending[1]

    def cancel(self, client_id: int) -> None:
        """Forget ``client_id``'s request (the dialog was cancelled)."""
        with self._lock:
            self._pending.pop(client_id, None)
