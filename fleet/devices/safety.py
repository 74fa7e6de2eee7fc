"""Per-arm safety state of the agent: the stop latch, standstill, the ownership lease and the
coordinator watchdog. Pure, with an injected clock (monotonic seconds); the agent does the I/O.

The rules:
- a stop latches at once and stays latched until an explicit reset; while latched every motion
  command is refused; the stop command is repeated until feedback shows the arm still;
- a reset never moves the arm: the agent makes the measured pose the target;
- one owner at a time: a motion command from someone else while a lease is held is refused
  (3207) unless it asks to take over; a lease expires when its holder goes silent;
- an arm moving under a coordinator's command is held, and latched, when that coordinator's
  heartbeat stops for longer than the watchdog period.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fleet.d1.standstill import Standstill  # the one definition of "still"

RESET_IDS_KEPT = 256
"""Stop ids an operator reset, remembered so their repeats (heartbeat) do not re-latch."""
SUPERSEDED_IDS_KEPT = 64
"""Stop ids replaced by a newer stop before a reset (released by that reset too); a flood of
distinct stop ids keeps only the newest."""
STOP_CAUSES_KEPT = 8
"""Distinct (who, why) of the stops active on one arm that its status names (issue 26: a second
stop replaced the first one's reason); more are counted ("and 3 more")."""
STOP_REASON_CHARS = 1000
"""The status payload's ``stop_reason`` is Text (at most 1024 characters)."""
STOP_REPEAT_S = 0.2
"""Until the arm is seen still, the stop command is re-sent every 0.2 s (two control cycles):
a stop is not trusted to one DDS sample or to an ack the arm may not send."""
STAMP_AHEAD_LIMIT_S = 2.0
"""A sender's stamp further ahead of the receiver's clock than this is a wrong clock (or a
forgery): a reset so stamped is refused, a stop so stamped latches all the same, and both are
counted. Hosts keep NTP time (milliseconds apart)."""
STAMP_WINDOW_S = 3.0
"""How far before its arrival a sender's stamp may place a stop or a reset. A stop's datagram
copy overtakes a reset still on its way over TCP by less than this; an older stamp (a slow
clock, a stamp of 0) is read as this long before the arrival."""


def stamp_order(stamp_ns: int, arrival_ns: int) -> int:
    """Where a stop or reset stands in a unit's order: its sender's stamp, bounded by the
    receiver's clock: never after its arrival (a clock ahead, ``2**63-1``), never more than
    ``STAMP_WINDOW_S`` before it (a clock behind, ``0``). So no sender's clock can order a
    message beyond the few seconds in which two paths may swap it with another."""
    return min(arrival_ns, max(stamp_ns, arrival_ns - int(STAMP_WINDOW_S * 1e9)))


def seconds_ahead(stamp_ns: int, arrival_ns: int) -> float | None:
    """How far ``stamp_ns`` is ahead of the receiver's clock, when more than
    ``STAMP_AHEAD_LIMIT_S`` (else None)."""
    ahead_s = (stamp_ns - arrival_ns) / 1e9
    return ahead_s if ahead_s > STAMP_AHEAD_LIMIT_S else None


@dataclass(frozen=True)
class ResetOutcome:
    """What a reset did to one unit: ``released`` its stop, found it ``not_stopped``, ``kept``
    the stop (one put after the reset is latched) or ``refused`` the reset (its stamp is far
    ahead of the unit's clock); ``detail`` says why, for the operator."""

    outcome: str
    released: ActiveStop | None = None
    detail: str = ""


@dataclass
class ActiveStop:
    """A latched stop on one arm."""

    stop_id: str
    source: str
    reason: str
    received_ns: int
    received_s: float
    action: str = "hold"
    dds_written_ns: int | None = None
    still_ns: int | None = None
    confirmed_ns: int | None = None
    """``unload``/``power_off``: when the arm's own status showed it unloaded / unpowered (the
    D1 is reported to acknowledge ``power=0`` and ignore it: only its status confirms)."""
    last_sent_s: float = 0.0
    detail: str | None = None
    """Why the stop's command was not written (a hold with no fresh pose), for its ack."""
    stamp_ns: int | None = None
    """When its sender put it (its ``stamp_ns``; None for the agent's own stops)."""

    @property
    def done(self) -> bool:
        """Confirmed by feedback: still, and for unload/power_off also by the arm's status."""
        return self.still_ns is not None and (
            self.action == "hold" or self.confirmed_ns is not None
        )


@dataclass
class Lease:
    """Who may move the arm, until when (monotonic seconds)."""

    owner: str
    expires_s: float
    since_s: float
    """When this owner took the arm (kept while it renews the lease)."""


class LeaseRefused(Exception):
    """Motion from a non-owner while a lease is held; ``holder`` says who holds it."""

    def __init__(self, holder: str, remaining_s: float) -> None:
        super().__init__(
            f"held by {holder!r}: its lease expires in {remaining_s:.1f} s unless renewed. "
            "To take the arm anyway: --takeover on the command line, takeover=True in the API"
        )
        self.holder = holder


@dataclass
class ArmSafety:
    """Stop latch, lease and watchdog of one arm."""

    lease_s: float
    watchdog_s: float
    stop: ActiveStop | None = None
    reset_stop_ids: dict[str, None] = field(default_factory=dict)  # insertion-ordered set
    superseded_ids: list[str] = field(default_factory=list)
    standstill: Standstill = field(default_factory=Standstill)
    lease: Lease | None = None
    watched_by: str | None = None
    watched_since_s: float = 0.0
    last_reason: str | None = None
    newest_stamp_ns: int | None = None
    """The newest order (``stamp_order``) of the stops acted on since the last reset: a reset
    ordered before it releases nothing (see ``answer_reset``)."""
    causes: dict[tuple[str, str], None] = field(default_factory=dict)
    """(source, reason) of every stop active since the latch, in arrival order (at most
    STOP_CAUSES_KEPT); ``more_causes`` counts the others."""
    more_causes: int = 0
    persist_error: str | None = None
    """Why the latched stop could not be written to disk (None: it was, or nothing to write):
    an agent restart would forget it, so the status says so (``stop_reason``)."""

    # ------------------------------------------------------------------ stop latch

    @property
    def latched(self) -> bool:
        """True while a stop is latched."""
        return self.stop is not None

    def is_current(self, stop_id: str) -> bool:
        """True when ``stop_id`` is the stop latched now (its repeat deserves a fresh ack)."""
        return self.stop is not None and self.stop.stop_id == stop_id

    def latch(
        self,
        stop_id: str,
        source: str,
        reason: str,
        now_s: float,
        now_ns: int,
        action: str = "hold",
        stamp_ns: int | None = None,
    ) -> bool:
        """Latch a stop; False if this stop is already latched or was reset (a repeat, known by
        its id). ``stamp_ns``: when its sender put it. A stop is never refused for its stamp:
        a late copy of a stop whose id was forgotten latches again (safe: reset again)."""
        if (
            stop_id in self.reset_stop_ids
            or stop_id in self.superseded_ids  # a repeat of a stop acted on while latched
            or (self.stop is not None and self.stop.stop_id == stop_id)
        ):
            return False
        self._saw_stamp(stamp_ns, now_ns)
        if self.stop is None:
            self.standstill.clear()
            self.causes.clear()
            self.more_causes = 0
        else:
            self.superseded_ids.append(self.stop.stop_id)  # reset releases it too
            del self.superseded_ids[:-SUPERSEDED_IDS_KEPT]
        self.stop = ActiveStop(stop_id, source, reason, now_ns, now_s, action, stamp_ns=stamp_ns)
        self._add_cause(source, reason)
        self.watched_by = None
        self.lease = None  # a stop ends every ownership: whoever resets decides who goes next
        return True

    def _saw_stamp(self, stamp_ns: int | None, now_ns: int) -> None:
        """The newest order of any stop acted on since the last reset (latched, superseded or
        noted): a reset ordered before it releases nothing. Copies of one stop on two paths
        arrive in either order, so the latched stop is not always the newest one."""
        if stamp_ns is None:
            return
        order = stamp_order(stamp_ns, now_ns)
        if self.newest_stamp_ns is None or order > self.newest_stamp_ns:
            self.newest_stamp_ns = order

    def note_also_stopped_by(
        self,
        stop_id: str,
        source: str = "",
        reason: str = "",
        stamp_ns: int | None = None,
        now_ns: int = 0,
    ) -> None:
        """While latched, ``stop_id`` (repeated by a heartbeat) also asks for this stop: the
        reset releases it with the latched one, so its repeats do not latch again; its
        ``source`` and ``reason`` join the stop's causes."""
        if stop_id in self.reset_stop_ids or stop_id in self.superseded_ids:
            return
        self._saw_stamp(stamp_ns, now_ns)
        self.superseded_ids.append(stop_id)
        del self.superseded_ids[:-SUPERSEDED_IDS_KEPT]
        if source and self.stop is not None:
            self._add_cause(source, reason)

    def _add_cause(self, source: str, reason: str) -> None:
        """Remember who stopped the arm and why (a repeat of a known pair adds nothing) and
        say them all in ``last_reason``, compactly: ``stopped by cli@pc: test; then by
        viewer``."""
        cause = (source, reason)
        if cause not in self.causes:
            if len(self.causes) < STOP_CAUSES_KEPT:
                self.causes[cause] = None
            else:
                self.more_causes += 1
        parts = [who + (f": {why}" if why else "") for who, why in self.causes]
        text = "stopped by " + "; then by ".join(parts)
        if self.more_causes:
            text += f"; and {self.more_causes} more"
        if len(text) > STOP_REASON_CHARS:
            text = text[: STOP_REASON_CHARS - 3] + "..."
        self.last_reason = text

    @property
    def stop_reason(self) -> str | None:
        """What a status says about the latch (None: not latched): who stopped the unit and
        why, and, when the stop could not be persisted, that a restart would forget it."""
        if self.stop is None:
            return None
        reason = self.last_reason or "stopped"
        if self.persist_error is None:
            return reason
        why = self.persist_error[:300]
        note = f" [NOT PERSISTED ({why}): a restart of its agent would forget this stop]"
        return reason[: STOP_REASON_CHARS - len(note)] + note

    def needs_resend(self, now_s: float) -> bool:
        """The stop should be written again: not yet confirmed by feedback (``done``) and the
        repeat period passed."""
        stop = self.stop
        return stop is not None and not stop.done and now_s - stop.last_sent_s >= STOP_REPEAT_S

    def on_status(self, enabled: bool, powered: bool, now_ns: int) -> bool:
        """Feed the arm's status; True when it has just confirmed an unload / power-off stop."""
        stop = self.stop
        if stop is None or stop.confirmed_ns is not None:
            return False
        if (stop.action == "unload" and not enabled) or (
            stop.action == "power_off" and not powered
        ):
            stop.confirmed_ns = now_ns
            return True
        return False

    def on_angles(self, angles_deg: tuple[float, ...], now_ns: int, now_s: float) -> bool:
        """Feed one angle report; True when a latched stop has just been confirmed still."""
        self.standstill.add(angles_deg, now_ns)
        if self.watched_by is not None and self.standstill.still and self._owner_quiet(now_s):
            self.watched_by = None  # the owner's command is over: it stopped commanding
        stop = self.stop
        since_ns = self.standstill.still_since_ns
        if stop is not None and stop.still_ns is None and since_ns is not None:
            # Still since the first report the others agree with; not before the stop acted
            # (an arm already still when it came: from the stop's write, or its receipt).
            stop.still_ns = max(since_ns, stop.dds_written_ns or stop.received_ns)
            return True
        return False

    def on_still_report(self, still: bool, now_s: float) -> None:
        """A device's own standstill report: a still device whose owner went quiet ends the
        watch (its command is over), as ``on_angles`` does for an arm."""
        if self.watched_by is not None and still and self._owner_quiet(now_s):
            self.watched_by = None

    def confirm(self, now_ns: int) -> bool:
        """A device's state shows the stop action done: the stop is confirmed (still and
        acted on); True the first time."""
        stop = self.stop
        if stop is None or stop.done or stop.dds_written_ns is None:
            return False
        stop.still_ns = stop.still_ns or now_ns
        stop.confirmed_ns = now_ns
        return True

    def reset(self, stamp_ns: int | None = None, now_ns: int = 0) -> ActiveStop | None:
        """``answer_reset``; the stop it released, if any."""
        return self.answer_reset(stamp_ns, now_ns).released

    def answer_reset(self, stamp_ns: int | None, now_ns: int) -> ResetOutcome:
        """Release the latch (operator action) unless a stop ordered after the reset is latched.

        Stops and resets are ordered by the receiver's clock (``stamp_order``): the sender's
        stamp counts only within the few seconds before the arrival, so a stop's datagram copy
        that overtook a reset still on its way over TCP is not released by it (nor, by
        remembering its id, is the stop's own reliable copy made a "repeat"), while no clock
        ahead, behind or forged can make a stop ignored or a reset outlast its arrival. A reset
        stamped further ahead than ``STAMP_AHEAD_LIMIT_S`` is refused (a wrong clock)."""
        if stamp_ns is not None:
            ahead_s = seconds_ahead(stamp_ns, now_ns)
            if ahead_s is not None:
                return ResetOutcome(
                    "refused",
                    detail=f"the reset's stamp is {ahead_s:.1f} s ahead of this agent's clock "
                    f"(at most {STAMP_AHEAD_LIMIT_S:g} s): fix the sender's clock (NTP) "
                    "and reset again",
                )
        stop = self.stop
        if stop is None:
            return ResetOutcome("not_stopped", detail="it was not stopped")
        if (
            stamp_ns is not None
            and self.newest_stamp_ns is not None
            and self.newest_stamp_ns > stamp_order(stamp_ns, now_ns)
        ):
            behind_s = (now_ns - stamp_ns) / 1e9
            clock = (
                f" (the reset's stamp is {behind_s:.1f} s behind this agent's clock)"
                if behind_s > 1.0
                else ""
            )
            return ResetOutcome(
                "kept",
                detail=f"a stop put after this reset is latched (by {stop.source}){clock}: "
                "reset again",
            )
        self.stop = None
        self.newest_stamp_ns = None
        for stop_id in (*self.superseded_ids, stop.stop_id):
            self.reset_stop_ids[stop_id] = None
        self.superseded_ids.clear()
        self.causes.clear()
        self.more_causes = 0
        while len(self.reset_stop_ids) > RESET_IDS_KEPT:
            del self.reset_stop_ids[next(iter(self.reset_stop_ids))]
        return ResetOutcome("released", stop, detail=f"released the stop by {stop.source}")

    # ------------------------------------------------------------------ lease

    def check_owner(self, owner: str | None, takeover: bool, now_s: float) -> None:
        """Raise LeaseRefused unless ``owner`` may move the arm now; renews/takes the lease."""
        lease = self.lease
        if lease is not None and lease.expires_s <= now_s:
            lease = self.lease = None
        if lease is not None and lease.owner != owner and not takeover:
            raise LeaseRefused(lease.owner, lease.expires_s - now_s)
        if self.watched_by is not None and owner != self.watched_by:
            self.watched_by = None  # someone else commands the arm now
        if owner is not None:
            since_s = lease.since_s if lease is not None and lease.owner == owner else now_s
            self.lease = Lease(owner, now_s + self.lease_s, since_s)
        elif takeover:
            self.lease = None

    def holder(self, now_s: float) -> Lease | None:
        """The lease in force at ``now_s`` (None when nobody holds the arm or it expired)."""
        lease = self.lease
        return lease if lease is not None and lease.expires_s > now_s else None

    def release(self, owner: str) -> bool:
        """``owner`` gives the arm up (and ends its watch); False if it did not hold it."""
        if self.watched_by == owner:
            self.watched_by = None
        if self.lease is not None and self.lease.owner == owner:
            self.lease = None
            return True
        return False

    # ------------------------------------------------------------------ watchdog

    def watch(self, coordinator: str, now_s: float) -> None:
        """The arm moves under ``coordinator``'s command: arm the watchdog. The watch lasts
        while the owner keeps commanding the arm (its lease is fresh) or the arm still moves,
        and ends when the owner releases the arm, another owner takes it, or a stop latches.
        So a streaming player that dies mid-script gets its arms held and latched, while an
        owner that finished (released, or silent for ``lease_s`` with the arm still) does not."""
        self.watched_by = coordinator
        self.watched_since_s = now_s
        self.standstill.clear()

    def _owner_quiet(self, now_s: float) -> bool:
        lease = self.lease
        return lease is None or lease.owner != self.watched_by or lease.expires_s <= now_s

    def watchdog_expired(self, last_heartbeat_s: float | None, now_s: float) -> bool:
        """True when the arm moves under a coordinator whose heartbeat is older than allowed.
        The watch's start counts as a beat: an agent that has not heard the commander yet (it
        just started) gives it ``watchdog_s`` to be heard, not zero."""
        if self.watched_by is None or self.latched:
            return False
        heard_s = max(self.watched_since_s, last_heartbeat_s or self.watched_since_s)
        return now_s - heard_s > self.watchdog_s
