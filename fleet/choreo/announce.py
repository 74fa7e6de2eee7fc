"""What a choreography player tells the fleet about itself: its ``ChoreoStatus`` on
``choreo/<principal>`` (the viewer shows it, and logs a dance that stopped with the reason).

The player was silent on the key space: when the demo's dance stopped, its reason went to the
player's own output only, and the viewer showed arms standing still. So the player puts its
state when it starts, at each step, every ``REPEAT_S`` while it plays (a viewer that opens
later, or misses a put, learns it) and once when it ends. States are latest-wins and dropped
under congestion like the other states; the end is put with congestion control BLOCK (it is
put once and must not be dropped: the stop path's lesson). A viewer that hears nothing for
``SILENT_S`` from a player it saw playing says so. Called on the player's own thread only.
"""

from __future__ import annotations

import logging
import time

import zenoh

from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode

log = logging.getLogger("fleet.choreo")

REPEAT_S = 1.0
"""A playing player repeats its state this often."""
SILENT_S = 3.0 * REPEAT_S
"""A player seen playing that put nothing for this long is gone (killed, or its host hangs)."""


class PlayAnnouncer:
    """The ``ChoreoStatus`` of one player (``player``: its owner id) of ``script``."""

    def __init__(
        self,
        session: zenoh.Session,
        space: keys.KeySpace,
        principal: str,
        player: str,
        script: str,
    ) -> None:
        self.key = space.choreo_of(principal)
        self.player = player
        self.script = script
        self._session = session
        self._publisher: zenoh.Publisher | None = session.declare_publisher(self.key)
        self._shown: tuple[int, str] | None = None
        self._shown_at = -float("inf")
        self.ended: m.ChoreoStatus | None = None
        """The end as announced (None while playing)."""

    def _status(self, state: str, reason: str, iteration: int, step: str) -> m.ChoreoStatus:
        return m.ChoreoStatus(
            stamp_ns=time.time_ns(),
            player=self.player,
            script=self.script,
            state=state,  # type: ignore[arg-type]
            reason=reason,
            iteration=iteration,
            step=step,
        )

    def playing(self, iteration: int, step: str) -> None:
        """The play is at ``step`` of pass ``iteration``: put when that changed, or every
        ``REPEAT_S``."""
        now = time.monotonic()
        if self.ended is not None or (
            (iteration, step) == self._shown and now - self._shown_at < REPEAT_S
        ):
            return
        self._shown, self._shown_at = (iteration, step), now
        if self._publisher is not None:
            self._publisher.put(encode(self._status("playing", "", iteration, step)))

    def end(self, ok: bool, reason: str) -> None:
        """The play ended (``ok``: completed; else aborted, ``reason`` says why): put once."""
        if self.ended is not None:
            return
        iteration, step = self._shown or (0, "")
        status = self._status("completed" if ok else "aborted", reason, iteration, step)
        self.ended = status
        try:
            self._session.put(
                self.key, encode(status), congestion_control=zenoh.CongestionControl.BLOCK
            )
        except zenoh.ZError as exc:  # a closed session: the play's end is in our log anyway
            log.warning("could not announce the end of %r on %s: %s", self.script, self.key, exc)

    def close(self) -> None:
        """Undeclare the publisher (idempotent)."""
        publisher, self._publisher = self._publisher, None
        if publisher is not None:
            publisher.undeclare()
