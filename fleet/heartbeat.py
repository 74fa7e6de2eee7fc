"""The one heartbeat loop: a ``Heartbeat`` on ``heartbeat/<principal>`` every period.

Agents treat every heartbeat publisher as a commander to watch: an arm moved by a commander
whose beat stops is held by its agent. The coordinator runs ``beat_until`` on its own guarded
thread (its latched stops ride in every beat, its fleet state and diag are put after a beat);
a choreography player or a mirror runs it through ``Liveness``, a thread of its own.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode
from fleet.wire.stoppath import DatagramSession, TwoPathPublisher

log = logging.getLogger("fleet.heartbeat")

HEARTBEAT_PERIOD_S = 0.1
"""A commander's beat (10 Hz): well inside the agents' default ``watchdog_s`` of 0.5 s."""
COPY_OFFSETS = (0.25, 0.75)
"""When a beat's datagram copies go, in periods after its TCP copy (``beat_until``)."""


def _no_stops() -> dict[str, m.StopRequest]:
    return {}


def beat_until(
    stopping: threading.Event,
    publisher: zenoh.Publisher | TwoPathPublisher,
    sender: str,
    period_s: float,
    stops: Callable[[], dict[str, m.StopRequest]] = _no_stops,
    after: Callable[[int, int], None] | None = None,
    watched: Callable[[], bool] | None = None,
) -> None:
    """Put a beat of ``sender`` every ``period_s`` until ``stopping`` is set; ``stops`` gives the
    latched stops to repeat, ``after(seq, stamp_ns)`` runs after each beat. Fixed rate: a late
    beat is followed by the next on schedule, not by a burst.

    On two paths (``TwoPathPublisher``) each beat's datagram copy goes twice, a quarter and
    three quarters of a period after its TCP copy. Measured at 10 % loss per link (34 % per
    copy from coordinator to agent) with one datagram copy: a false watchdog stop
    (``watchdog_s`` 0.5 s) about once a minute (five copies lost while the TCP copies waited
    for a retransmission); two make five periods lost 0.34^10 = 2e-5.

    The copies cost every agent two more samples a period (measured: +0.7-0.9 % of a core per
    idle agent), and they only matter to a unit whose watchdog watches ``sender``. ``watched``
    (None: always) says whether one may: while it says no, a beat goes on TCP only and says
    so (``Heartbeat.datagram_copies`` 0), and no agent takes the missing copies for a deaf
    datagram session."""
    seq = 0
    next_beat = time.monotonic()
    while not stopping.is_set():
        latched = stops()
        copies = (
            isinstance(publisher, TwoPathPublisher)
            and publisher.has_datagram()
            and (watched is None or bool(latched) or watched())
        )
        beat = m.Heartbeat(
            time.time_ns(),
            sender,
            seq,
            period_s,
            latched,
            datagram_copies=len(COPY_OFFSETS) if copies else 0,
        )
        if stopping.is_set():
            return  # stopped (a thread failed) while composing: not one more beat
        data = encode(beat)
        if isinstance(publisher, TwoPathPublisher):
            publisher.reliable.put(data)
        else:
            publisher.put(data)
        if after is not None:
            after(seq, beat.stamp_ns)
        seq += 1
        if isinstance(publisher, TwoPathPublisher) and copies:
            for offset in COPY_OFFSETS:
                if stopping.wait(max(0.0, next_beat + period_s * offset - time.monotonic())):
                    return
                publisher.put_datagram(data)
        next_beat += period_s
        stopping.wait(max(0.0, next_beat - time.monotonic()))


class Liveness:
    """The heartbeat of commander ``owner`` (10 Hz, own thread). A context manager."""

    def __init__(
        self,
        session: zenoh.Session,
        space: keys.KeySpace,
        owner: str,
        principal: str,
        datagram: DatagramSession | None = None,
    ) -> None:
        """``datagram``: the beats' datagram path (``FleetClient.datagram``; none: TCP only)."""
        self.owner = owner
        key = space.heartbeat_of(principal)  # the router lets only `principal` publish it
        self._pub = TwoPathPublisher(session, datagram or DatagramSession(None), key)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="liveness", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            beat_until(self._stop, self._pub, self.owner, HEARTBEAT_PERIOD_S)
        except BaseException:
            log.exception("liveness thread failed: agents will hold the arms")
            raise

    def close(self) -> None:
        """Stop beating (agents then hold arms still moving under this owner); idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._pub.undeclare()

    def __enter__(self) -> Liveness:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
