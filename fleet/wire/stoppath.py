"""The two paths of a stop: every stop, its repeats, its acks and the heartbeats that repeat
latched stops are put twice: once reliable on their key (real-time priority, never waiting for
room: ``REPEATED_QOS``) on the process's session over TCP, and once express on the key's
datagram twin (``fleet/<fleet>/dg/<key>``: ``keys.datagram_key``) on its datagram session over
UDP (``fleet.wire.session.Datagram``). The datagram copy never queues behind a TCP
retransmission; the receivers subscribe to the key on one session and to its twin on the
other, and de-duplicate (agents by ``stop_id``; acks and heartbeats are latest-wins).

The datagram copy is a plain ``Session.put`` of the full key, never a declared publisher, and
the datagram sessions subscribe with wildcards only: a declared key (or a declared prefix of
it) is sent as a number, and a datagram referring to a declaration that was lost (or, measured
with one session of two links, still on its way over TCP) is dropped by the router for good
("unknown scope").

Over UDP, what rides the datagram link besides the copies is lossy too: a session's
declarations and its link's re-making. So a datagram session subscribes with no declared
prefix (``keys.datagram_subscription``), declares its subscriptions again every
``REDECLARE_S``, and is replaced by a new session when its link to the router was re-made
(``DatagramSession._replace``): measured in the lab, after spells of 30 % loss datagram-only
stops reached none, or only some, of 5 agents until the sending client restarted.

The datagram session is UDP beside ``tcp/`` endpoints and QUIC datagrams (authenticated, under
the router's access control) beside ``tls/`` ones (``fleet.wire.session.datagram_twin``).
Without one (``datagram = false``, UDP blocked, an older router) only the reliable path is
used, as before.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from fleet.wire import keys
from fleet.wire.session import DATAGRAM_LEASE_S, close_bounded

log = logging.getLogger("fleet.stoppath")

JSON = zenoh.Encoding.APPLICATION_JSON

RELIABLE_QOS: dict[str, object] = {
    "congestion_control": zenoh.CongestionControl.BLOCK,
    "priority": zenoh.Priority.REAL_TIME,
}
"""Resets (put once): never dropped under congestion, sent first."""

REPEATED_QOS: dict[str, object] = {
    "congestion_control": zenoh.CongestionControl.DROP,
    "priority": zenoh.Priority.REAL_TIME,
}
"""The reliable copy of what is repeated until confirmed (stops every 100 ms until every unit
confirmed, an ack with each repeat, beats at 10 Hz): DROP. Measured at 30 % loss: with BLOCK a
put waited while TCP was backed off (the queue towards the router full), up to 5 s, and held
the thread that puts: the agent's safety thread (no new stop acted on meanwhile), the
coordinator's beat (a false watchdog stop on every arm), the client's stop repeats."""

DATAGRAM_QOS: dict[str, object] = {
    "congestion_control": zenoh.CongestionControl.DROP,
    "priority": zenoh.Priority.REAL_TIME,
    "express": True,
}
"""The datagram copy: never waits (DROP: another copy follows within 10-100 ms), not batched."""

REDECLARE_S = 5.0
"""How often a datagram session declares its subscriptions again. Declarations ride the same
lossy UDP link as the copies, and Zenoh does not send them again: one lost when the session
(re)connected under loss leaves the router without it, and no copy comes for the session's
life. A new declaration of the same key heals that within this period, for one small message
per subscription every 5 s."""

LINK_CHECK_S = 1.0
"""How often a datagram session looks whether its link to the router was made anew, or it has
gone deaf (then it is replaced: ``DatagramSession._replace``)."""

DEAF_S = 3.0
"""A datagram session that heard copies on a watched subscription before, and none for this
long while the same traffic kept coming over the reliable path (``heard_reliably`` within
``RELIABLE_FRESH_S``), is deaf and is replaced. Measured in the lab after spells of 30 % loss:
datagram-only stops reached none of 5 agents with no link re-made. The agents' watch is the
coordinator's beat (10 Hz on both paths): at 30 % loss per link a copy crosses four links with
24 %, so 30 copies in a row are all lost with 0.03 %."""

RELIABLE_FRESH_S = 1.0
"""The reliable path counts as delivering when it did within this long."""

REOPEN_MAX_S = 10.0
"""The longest wait between two tries to open a datagram session that found no router."""

DATAGRAM_CLOSE_WAIT_S = 1.0
"""A datagram session's close may hold a shutdown this long (QUIC's close waited 10 s for a
router that was gone: every secure process's shutdown after its router's)."""

BURST_INTERVAL_S = 0.01
"""A new stop's datagram copies go every 10 ms for its first ``BURST_S`` (25 copies, ~8 kB).
Sized by the lab: a copy from a client to an agent crosses four network links (the client's,
the router's twice, the arm host's), so at 30 % loss per link 76 % of the copies are lost;
6 copies (a 50 ms burst) all failed for 19 % of the arms (measured: received after the next
100 ms repeat or later), 22 copies within 300 ms all fail for 0.2 %. At 10 % (34 % per copy)
the first two copies already arrive with 88 %."""
BURST_S = 0.25


class DatagramSession:
    """A process's datagram session, opened by ``opener`` (None: no datagram path). ``session``
    is None until it is open. ``start`` opens it on a thread of its own, so that a client that
    stops at once never waits for the second handshake (under loss it may take seconds; the
    reliable path does not wait for it); ``open`` opens it here. ``close`` is idempotent."""

    def __init__(
        self,
        opener: Callable[[], zenoh.Session | None] | None,
        endpoints: str | None = None,
        beside: zenoh.Session | None = None,
    ) -> None:
        self._opener = opener
        self._beside = beside
        """The process's reliable session: while it has its router, a datagram session without
        one is refused by that router, not waiting for it (``_refresh_once``)."""
        self._retry: threading.Thread | None = None
        self._closing = threading.Event()
        self._endpoints = endpoints
        """Where it connects (``path``), e.g. ``quic/10.0.0.1:7447?rel=0``."""
        self._lock = threading.Lock()
        self._session: zenoh.Session | None = None  # guarded by _lock
        self._closed = False
        self._thread: threading.Thread | None = None
        self._subscriptions: list[DatagramSubscription] = []  # guarded by _lock
        self._refresher: threading.Thread | None = None
        self._heard_at: float | None = None
        """When a watched subscription last heard a copy on the current session (None: not
        yet, so a sender without a datagram path never makes a session look deaf)."""
        self._reliable_at = float("-inf")
        self._reliable_since = float("-inf")
        """When the reliable path's current spell of delivery began: copies that only now
        became due (a sender that sends them only while watched) get ``DEAF_S`` from there."""
        self.replaced = 0
        """Times the session was replaced (its link re-made, or deaf)."""

    def heard_reliably(self) -> None:
        """The watched traffic, with copies due on this path, arrived over the reliable path
        (the deaf check's reference)."""
        now = time.monotonic()
        if now - self._reliable_at >= RELIABLE_FRESH_S:
            self._reliable_since = now
        self._reliable_at = now

    def _heard(self) -> None:
        self._heard_at = time.monotonic()

    def deaf(self, now: float) -> bool:
        """Whether the session heard watched copies before and none for ``DEAF_S`` while the
        reliable path delivered (all that time) traffic whose copies were due."""
        heard = self._heard_at
        return (
            heard is not None
            and now - max(heard, self._reliable_since) > DEAF_S
            and now - self._reliable_at < RELIABLE_FRESH_S
        )

    @property
    def session(self) -> zenoh.Session | None:
        """The open datagram session, or None (not open yet, none, or closed)."""
        with self._lock:
            return self._session

    def path(self) -> str | None:
        """Its endpoints while the session is open and connected to a router, else None
        (what ``info/`` reports and ``fleet doctor`` checks)."""
        session = self.session
        if session is None or session.is_closed() or not list(session.info.routers_zid()):
            return None
        return self._endpoints

    def subscription(self, key: str) -> str:
        """What this session subscribes to for ``key``'s datagram copies. Over UDP,
        ``keys.datagram_subscription`` (no declared prefix, so no put of this session refers
        to a declaration the router may have lost); over QUIC the copy's own key (declarations
        take its reliable stream)."""
        endpoints = self._endpoints or ""
        if endpoints and all(e.strip().startswith("udp/") for e in endpoints.split(",")):
            return keys.datagram_subscription(key)
        return keys.datagram_key(key)

    def subscribe(
        self, key: str, handler: Callable[[zenoh.Sample], None], watched: bool = False
    ) -> DatagramSubscription:
        """Receive ``key``'s datagram copies (``subscription``) on ``handler`` until
        ``cancel``: declared once the session is open (now, or when a later try opens it) and
        declared again every ``REDECLARE_S`` (the old declaration undeclared after the new
        one: a copy in between may come twice; every receiver de-duplicates). ``watched``:
        traffic that also comes reliably (``heard_reliably``), so its silence here makes the
        session deaf (``deaf``)."""
        if watched:
            handler = self._watching(handler)

        entry = DatagramSubscription(self, self.subscription(key), handler)
        with self._lock:
            self._subscriptions.append(entry)
            session = self._session
        if session is not None:
            entry.declare(session)
        return entry

    def _watching(self, handler: Callable[[zenoh.Sample], None]) -> Callable[[zenoh.Sample], None]:
        """``handler``, noting each copy as heard first (run where ``handler`` would run: a
        ``direct`` callback stays on the receiving thread)."""

        def heard_then(sample: zenoh.Sample) -> None:
            self._heard()
            handler(sample)

        if isinstance(handler, zenoh.handlers.Callback):
            watching: Callable[[zenoh.Sample], None] = zenoh.handlers.Callback(
                heard_then, handler.drop, indirect=handler.indirect
            )
            return watching
        return heard_then

    def _forget(self, entry: DatagramSubscription) -> None:
        with self._lock:
            if entry in self._subscriptions:
                self._subscriptions.remove(entry)

    def _refresh(self) -> None:
        seen: set[str] | None = None
        declared = time.monotonic()
        while not self._closing.wait(LINK_CHECK_S):
            try:
                now = time.monotonic()
                redeclare = now - declared >= REDECLARE_S
                seen = self._refresh_once(seen, redeclare)
                declared = now if redeclare else declared
            except Exception:  # never a crash: the reliable path still carries stops
                log.exception("refreshing the datagram session failed")

    def _refresh_once(self, seen: set[str] | None, redeclare: bool) -> set[str] | None:
        """Replace the session if its link to the router was made anew since the last look
        (``seen``: its links' local ends), is lost while the reliable session beside it has
        its router (that router holds a datagram session for ``DATAGRAM_LEASE_S`` and refuses
        the same session's reconnection meanwhile; a router gone altogether is waited for) or
        it is ``deaf``, else with ``redeclare`` declare its subscriptions again; the links now."""
        with self._lock:
            session, entries = self._session, list(self._subscriptions)
        if session is None or session.is_closed():
            return seen
        links = {str(link.src) for link in session.info.links()}
        remade = seen is not None and bool(links) and not links & seen
        lost = seen is not None and not links and self._router_up()
        if remade or lost or self.deaf(time.monotonic()):
            if remade:
                log.warning("datagram session: its link to the router was re-made")
            elif lost:
                log.warning(
                    "datagram session: no link to the router, which the reliable session has; a "
                    "new session replaces it (the router refuses this one's reconnection for up "
                    "to %.0f s, its lease)",
                    DATAGRAM_LEASE_S,
                )
            else:
                self._heard_at = time.monotonic()  # a failed replacement is tried again later
                log.warning(
                    "datagram session deaf: no copy for %.0f s while the reliable path delivers",
                    DEAF_S,
                )
            fresh = self._replace(session)
            if fresh is not None:  # its links are looked at next time (none yet, maybe)
                return {str(link.src) for link in fresh.info.links()} or None
        if redeclare:
            for entry in entries:
                entry.declare(session)
        return links or seen  # no link, and no new session yet: tried again next time

    def _router_up(self) -> bool:
        """The reliable session beside this one has its router now."""
        beside = self._beside
        try:
            return (
                beside is not None
                and not beside.is_closed()
                and bool(list(beside.info.routers_zid()))
            )
        except zenoh.ZError:
            return False

    def _replace(self, old: zenoh.Session) -> zenoh.Session | None:
        """A new session in place of ``old``, whose link was re-made or which went deaf: a
        reconnection under loss left the router routing this session's copies to its old link,
        or without its declarations, for good (measured in the lab after 30 % loss:
        datagram-only stops reached none of 5 agents while every UDP link was up). A new
        session is a new transport at the router, its state made afresh."""
        opener = self._opener
        fresh = opener() if opener is not None else None
        if fresh is None:
            return None
        with self._lock:
            if self._closed or self._session is not old:
                stale, fresh = fresh, None
            else:
                self._session, stale = fresh, old
                self._heard_at = None  # judged again once the new session hears a copy
                self.replaced += 1
            entries = list(self._subscriptions)
        if fresh is not None:
            for entry in entries:
                entry.declare(fresh)
            log.warning("datagram session re-opened")
        close_bounded(stale, "datagram session", DATAGRAM_CLOSE_WAIT_S)
        return fresh

    def open(self) -> zenoh.Session | None:
        """Try to open it now; the session, or None. A try that finds no router (one
        restarting, a link still down) is tried again in the background, every 1 s, doubling
        up to ``REOPEN_MAX_S``, until one opens or ``close``: a process started at the wrong
        moment must not keep only the reliable path for its whole life (measured: a
        coordinator restarted while its router's UDP did not answer sent every later beat over
        TCP only, and at 10 % loss each arm tripped its watchdog 6-8 times in 40 s)."""
        session = self._try()
        configured = self._opener is not None and self._endpoints is not None
        if session is None and configured and self._retry is None and not self._closed:
            self._retry = threading.Thread(target=self._reopen, name="datagram-reopen", daemon=True)
            self._retry.start()
        return session

    def _try(self) -> zenoh.Session | None:
        with self._lock:
            if self._session is not None or self._closed:
                return self._session  # open already (never a second session), or closing
        opener = self._opener
        session = opener() if opener is not None else None
        with self._lock:
            if self._closed:
                late, session = session, None
            else:
                self._session, late = session, None
        if late is not None:
            close_bounded(late, "datagram session", DATAGRAM_CLOSE_WAIT_S)  # closed meanwhile
        if session is not None:
            with self._lock:
                entries = list(self._subscriptions)
                start = self._refresher is None and not self._closed
                if start:
                    self._refresher = threading.Thread(
                        target=self._refresh, name="datagram-redeclare", daemon=True
                    )
            for entry in entries:
                entry.declare(session)
            if start:
                assert self._refresher is not None
                self._refresher.start()
        return session

    def _reopen(self) -> None:
        wait_s = 1.0
        while not self._closing.wait(wait_s):
            try:
                if self._try() is not None:
                    log.warning("datagram path for stops open (a later try): %s", self._endpoints)
                    return
            except Exception:  # never a crash: stops keep the reliable path
                log.exception("reopening the datagram session failed")
            wait_s = min(wait_s * 2.0, REOPEN_MAX_S)

    def start(self) -> None:
        """Open it on a thread of its own (a failure is logged: stops then take the reliable
        path only)."""

        def run() -> None:
            try:
                self.open()
            except BaseException:
                log.exception("opening the datagram session failed: stops take TCP only")
                raise

        self._thread = threading.Thread(target=run, name="datagram-open", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Close the session (idempotent; waits up to 1 s for an opening in progress)."""
        with self._lock:
            self._closed = True
            session, self._session = self._session, None
        self._closing.set()
        for thread in (self._thread, self._retry, self._refresher):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=1.0)
        if session is not None:
            close_bounded(session, "datagram session", DATAGRAM_CLOSE_WAIT_S)


class DatagramSubscription:
    """One ``DatagramSession.subscribe``: its key, handler and current declaration."""

    def __init__(
        self, owner: DatagramSession, key: str, handler: Callable[[zenoh.Sample], None]
    ) -> None:
        self.key = key
        self._owner = owner
        self._handler = handler
        self._lock = threading.Lock()
        self._subscriber: zenoh.Subscriber[None] | None = None  # guarded by _lock
        self._cancelled = False

    def declare(self, session: zenoh.Session) -> None:
        """Declare it (again) on ``session``, then undeclare the declaration it replaces."""
        with self._lock:
            if self._cancelled:
                return
            new = session.declare_subscriber(self.key, self._handler)
            old, self._subscriber = self._subscriber, new
        _undeclare(old)

    def cancel(self) -> None:
        """Stop receiving (idempotent)."""
        self._owner._forget(self)
        with self._lock:
            self._cancelled = True
            subscriber, self._subscriber = self._subscriber, None
        _undeclare(subscriber)


def _undeclare(subscriber: zenoh.Subscriber[None] | None) -> None:
    """Undeclare ``subscriber`` if any; one of a session closed meanwhile has nothing to undo."""
    if subscriber is None:
        return
    try:
        subscriber.undeclare()  # type: ignore[no-untyped-call]
    except Exception:
        log.debug("undeclaring a datagram subscriber failed", exc_info=True)


class TwoPathPublisher:
    """One key, two paths: ``put`` sends the payload on the datagram session (first: it cannot
    be held up) and on a reliable publisher. ``undeclare`` is idempotent."""

    def __init__(self, session: zenoh.Session, datagram: DatagramSession, key: str) -> None:
        self.key = key
        self.datagram_key = keys.datagram_key(key)
        self._datagram = datagram
        self.reliable = session.declare_publisher(key, encoding=JSON, **REPEATED_QOS)  # type: ignore[arg-type]
        self._undeclared = False

    def put(self, payload: bytes | str) -> None:
        """Both paths."""
        self.put_datagram(payload)
        self.reliable.put(payload)

    def has_datagram(self) -> bool:
        """Whether a datagram session is open now (its copies may go)."""
        return self._datagram.session is not None

    def put_datagram(self, payload: bytes | str) -> None:
        """The datagram path only (the fast repeats of a stop's first 250 ms); nothing without
        a datagram session."""
        datagram = self._datagram.session
        if datagram is None:
            return
        try:
            datagram.put(self.datagram_key, payload, encoding=JSON, **DATAGRAM_QOS)  # type: ignore[arg-type]
        except zenoh.ZError as exc:  # closed meanwhile (shutdown): the reliable copy goes on
            log.debug("datagram put on %s failed: %s", self.key, exc)

    def undeclare(self) -> None:
        """Undeclare the reliable publisher (idempotent)."""
        if not self._undeclared:
            self._undeclared = True
            self.reliable.undeclare()  # type: ignore[no-untyped-call]


def stop_qos_overwrite(space: keys.KeySpace) -> list[dict[str, object]]:
    """The routers' QoS overwrite (Zenoh ``qos/network``) that pins the stops' QoS centrally:
    every stop, reset, stop ack and heartbeat put through a fleet router leaves it at real-time
    priority and express, whatever its publisher asked for (a third-party client's plain
    ``put`` on a stop key included). Reliability is not overwritable (Zenoh 1.10): the two paths
    keep theirs; congestion control is DROP on the way out of a router for every key
    (``fleet.wire.session.NEVER_WAIT_FOR_A_CONSUMER``)."""
    return [
        {
            "id": "d1_fleet_stops",
            "messages": ["put"],
            "key_exprs": [
                space.estop,
                f"{space.prefix}/**/{keys.ESTOP}",
                f"{space.prefix}/**/{keys.ESTOP_ACK}",
                space.heartbeat,
                # (the datagram copies' keys, fleet/<fleet>/dg/..., match the two wildcards
                # above; their heartbeats:)
                keys.datagram_key(space.heartbeat),
                # Resets too: on the reliable path a stop must not overtake the reset put before
                # it, nor a reset the stop (one priority, one order), whatever the client asked.
                space.reset,
                f"{space.prefix}/**/{keys.RESET}",
            ],
            "overwrite": {"priority": "real_time", "express": True},
        }
    ]
