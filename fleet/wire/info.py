"""Who runs in the fleet: every long-running process answers ``info/<role>/<instance>``.

``InfoService`` serves one process's ``ProcessInfo`` (role, principal, host, pid, version, its
wall clock, its metrics port); ``query_info`` asks every process at once. ``fleet doctor`` uses
the replies for the versions of every process and for the clock offset between hosts: each
reply carries the responder's ``time.time_ns()`` taken when it answered, and the asker notes
its own clock before and after, so offset = stamp - midpoint, within +/- half the round trip
(NTP's estimate, one exchange).

The Zenoh callback only queues the query (a callback must not call Zenoh); a thread of our own
replies. The queue is bounded: a flood of queries is dropped (a dropped query is answered with
nothing), counted in ``dropped``.
"""

from __future__ import annotations

import logging
import os
import queue
import re
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version

import zenoh

from fleet.wire import keys, payloads
from fleet.wire import messages as m

log = logging.getLogger("fleet.info")

MAX_PENDING = 64
REPLY_WAIT_S = 0.5
SETTLE_S = 2.0


def package_version() -> str:
    """The installed d1-fleet version, or ``(not installed)`` in a bare source tree."""
    try:
        return version("d1-fleet")
    except PackageNotFoundError:
        return "(not installed)"


def instance_name(host: str | None = None, pid: int | None = None) -> str:
    """``<host>-<pid>`` made usable in a key (dots and other characters become ``_``)."""
    host = host if host is not None else socket.gethostname()
    pid = pid if pid is not None else os.getpid()
    clean = re.sub(r"[^A-Za-z0-9_\-]", "_", host)[:40] or "host"
    if not clean[0].isalnum():
        clean = "h" + clean
    return f"{clean}-{pid}"


class InfoService:
    """Answers ``info/<role>/<instance>`` on ``session`` until closed. A context manager."""

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        role: str,
        principal: str,
        arms: list[str] | tuple[str, ...] = (),
        metrics_port: int | None = None,
        datagram: Callable[[], str | None] | None = None,
    ) -> None:
        self.key = keys.KeySpace(fleet).info(role, instance_name())
        self._template = m.ProcessInfo(
            role=role,
            principal=principal,
            host=socket.gethostname()[:128],
            pid=os.getpid(),
            version=package_version()[:32],
            started_ns=time.time_ns(),
            stamp_ns=0,
            arms=list(arms),
            metrics_port=metrics_port,
        )
        self._datagram = datagram
        """The stops' datagram path when open (``DatagramSession.path``), asked at each reply."""
        self.dropped = 0
        self._queries: queue.Queue[zenoh.Query | None] = queue.Queue(MAX_PENDING)
        self._closed = False
        self._thread = threading.Thread(target=self._serve, name="info", daemon=True)
        self._thread.start()
        self._queryable = session.declare_queryable(self.key, self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            self._queries.put_nowait(query)
        except queue.Full:
            self.dropped += 1  # dropping the query ends it with no reply

    def _serve(self) -> None:
        while True:
            query = self._queries.get()
            if query is None:
                return
            info = self._info()
            try:
                query.reply(self.key, m.encode(info), encoding=zenoh.Encoding.APPLICATION_JSON)
            except zenoh.ZError as exc:  # the asker went away, or the session is closing
                log.debug("info reply failed: %s", exc)
            finally:
                query.drop()  # type: ignore[no-untyped-call]

    def _info(self) -> m.ProcessInfo:
        return m.ProcessInfo(
            role=self._template.role,
            principal=self._template.principal,
            host=self._template.host,
            pid=self._template.pid,
            version=self._template.version,
            started_ns=self._template.started_ns,
            stamp_ns=time.time_ns(),
            arms=self._template.arms,
            metrics_port=self._template.metrics_port,
            datagram=self._datagram() if self._datagram is not None else None,
        )

    def close(self) -> None:
        """Undeclare the queryable, then stop the thread (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._queryable.undeclare()  # type: ignore[no-untyped-call]
        try:
            self._queries.put(None, timeout=1.0)
        except queue.Full:
            log.debug("info queue full at close")
        self._thread.join(timeout=2.0)

    def __enter__(self) -> InfoService:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class InfoReply:
    """One process's answer and the asker's clock around it."""

    key: str
    info: m.ProcessInfo
    sent_ns: int
    received_ns: int

    @property
    def offset_ms(self) -> float:
        """The responder's clock minus ours, in ms (NTP's one-exchange estimate)."""
        return (self.info.stamp_ns - (self.sent_ns + self.received_ns) / 2) / 1e6

    @property
    def uncertainty_ms(self) -> float:
        """Half the round trip: the offset is within +/- this of the truth."""
        return (self.received_ns - self.sent_ns) / 2e6


def query_info(
    session: zenoh.Session, fleet: str, timeout_s: float = REPLY_WAIT_S, rounds: int = 3
) -> tuple[list[InfoReply], int]:
    """Every process's info (the reply with the shortest round trip of ``rounds`` per key) and
    the number of undecodable replies. A session opened a moment ago may hear nothing for about
    0.5 s (measured: the router's own queryable answered a new client after 0.47 s): rounds
    that got nothing are repeated, for up to ``SETTLE_S``."""
    best: dict[str, InfoReply] = {}
    bad = 0
    settle_until = time.monotonic() + SETTLE_S
    done = 0
    while done < max(1, rounds):
        if not best and done and time.monotonic() < settle_until:
            time.sleep(0.1)  # nothing yet: do not count this round
            done -= 1
        sent_ns = time.time_ns()
        replies = session.get(
            keys.KeySpace(fleet).all_info,
            target=zenoh.QueryTarget.ALL,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=timeout_s,
        )
        for reply in replies:
            received_ns = time.time_ns()
            if reply.ok is None:
                continue
            try:
                info = payloads.PROCESS_INFO.decode(reply.ok.payload.to_bytes())
            except payloads.PayloadError:
                bad += 1
                continue
            key = str(reply.ok.key_expr)
            got = InfoReply(key, info, sent_ns, received_ns)
            if key not in best or got.uncertainty_ms < best[key].uncertainty_ms:
                best[key] = got
        done += 1
    return sorted(best.values(), key=lambda r: (r.info.role, r.key)), bad
