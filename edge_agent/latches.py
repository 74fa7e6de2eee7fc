"""Latched stops that survive an agent restart: one small file per stopped arm.

An agent killed (or crashed, or rebooted with its host) while its arm is stopped must bring the
arm back stopped: the stop is an operator's decision, released only by a reset. So every latch
is written to ``<state dir>/<fleet>/<arm>.stop.json`` (the StopRequest, written to a temporary
file, synced and renamed: never half written), and removed by a reset. At start-up the agent
latches every arm that has a file *before* it serves any command; the stop's action is written
as soon as the arm's feedback is fresh. A file that cannot be read still latches its arm (fail
safe), with a reason that says so.

Writing happens on a ``latches`` thread of its own (a synced write takes milliseconds, and a
flood of stops must not make the safety thread wait on the disk): ``remember``/``forget`` only
record the newest state per arm (latest wins), the thread writes it, and ``close`` writes what
is left. The state directory: ``--state-dir``, else ``$D1_FLEET_STATE_DIR``, else
``$XDG_STATE_HOME/d1-fleet`` (``~/.local/state/d1-fleet``).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path

from fleet.files import FileReadError, read_regular
from fleet.guard import ThreadGuard
from fleet.wire import messages as m
from fleet.wire import payloads

log = logging.getLogger("edge_agent.latches")

STATE_ENV = "D1_FLEET_STATE_DIR"
MAX_LATCH_BYTES = 64 * 1024
"""A latched stop is one small StopRequest: a bigger file is refused (and latches anyway)."""


def default_state_dir() -> Path:
    """Where agents keep their latched stops unless told otherwise."""
    given = os.environ.get(STATE_ENV)
    if given:
        return Path(given)
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "d1-fleet"


class LatchStore:
    """The latched stops of one fleet's arms on disk."""

    def __init__(self, directory: Path, fleet: str, guard: ThreadGuard) -> None:
        self.directory = directory / fleet
        self.directory.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._pending: dict[str, m.StopRequest | None] = {}  # arm -> latched stop, None: reset
        self._wake = threading.Event()
        self._closing = threading.Event()
        self.thread = guard.thread(self._run, "latches")

    def remember(self, arm: str, request: m.StopRequest) -> None:
        """``request`` is latched on ``arm`` (written soon, on the latches thread)."""
        with self._lock:
            self._pending[arm] = request
        self._wake.set()

    def forget(self, arm: str) -> None:
        """``arm`` was reset."""
        with self._lock:
            self._pending[arm] = None
        self._wake.set()

    def _run(self) -> None:
        while not self._closing.is_set():
            self._wake.wait(0.5)
            self._wake.clear()
            self._write_pending()

    def _write_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, {}
        for arm, request in pending.items():
            if request is None:
                self.clear(arm)
            else:
                self.save(arm, request)

    def close(self) -> None:
        """Stop the thread and write what is left (idempotent)."""
        self._closing.set()
        self._wake.set()
        if self.thread.is_alive() and self.thread is not threading.current_thread():
            self.thread.join(timeout=2.0)
        self._write_pending()

    def _path(self, arm: str) -> Path:
        return self.directory / f"{arm}.stop.json"

    def load(self, arm: str) -> m.StopRequest | None:
        """The stop latched on ``arm`` when its agent last ran, if any."""
        path = self._path(arm)
        try:
            data = read_regular(path, MAX_LATCH_BYTES, "latch file")
        except FileNotFoundError:
            return None
        except (FileReadError, OSError) as exc:
            return self._unreadable(arm, str(exc))
        try:
            return payloads.STOP.decode(data)
        except payloads.PayloadError as exc:
            return self._unreadable(arm, exc.why[:200])

    @staticmethod
    def _unreadable(arm: str, why: str) -> m.StopRequest:
        log.error("arm %s: its latched stop file is unreadable (%s): latched anyway", arm, why)
        return m.StopRequest(
            stamp_ns=time.time_ns(),
            source="edge-agent",
            stop_id=f"unreadable-latch-{arm}-{time.time_ns()}",
            reason=f"latched before a restart; the latch file was unreadable ({why})",
        )

    def save(self, arm: str, request: m.StopRequest) -> None:
        """Remember that ``request`` is latched on ``arm`` (atomic, synced)."""
        path = self._path(arm)
        temporary = path.with_suffix(".tmp")
        try:
            with open(temporary, "wb") as out:
                out.write(m.encode(request))
                out.flush()
                os.fsync(out.fileno())
            os.replace(temporary, path)
        except OSError as exc:
            log.error("arm %s: could not persist its latched stop (%s)", arm, exc)

    def clear(self, arm: str) -> None:
        """``arm`` was reset."""
        try:
            self._path(arm).unlink()
        except FileNotFoundError:
            return
        except OSError as exc:
            log.error("arm %s: could not remove its latched stop file (%s)", arm, exc)
