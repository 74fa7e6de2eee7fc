"""Latched stops that survive an agent restart: one small file per stopped unit.

An agent killed (or crashed, or rebooted with its host) while its arm is stopped must bring the
arm back stopped: the stop is an operator's decision, released only by a reset. So every latch
is written to ``<state dir>/<fleet>/domain-<domain>/<unit>.stop.json`` (the StopRequest, written
to a temporary file, synced and renamed: never half written), and removed by a reset. At
start-up the agent latches every unit that has a file *before* it serves any command; the
stop's action is written as soon as the unit's feedback is fresh. A file that cannot be read
still latches its unit (fail safe), with a reason that says so.

Keyed by fleet *and* DDS domain: two fleets named alike on one host (a demo beside a test run,
two labs) once shared one file per unit name, and one's reset released the other's latch. A
stop written by an older agent in ``<state dir>/<fleet>/<unit>.stop.json`` is read once at
start-up and moved to the new place (it must not be forgotten by the upgrade).

Nothing is read or written through a symbolic link: the ``<fleet>`` and ``domain-<n>`` entries
are opened with ``O_NOFOLLOW`` (a link there refuses to start the agent: ``LatchDirError``),
and every file operation is relative to that directory's descriptor, again with ``O_NOFOLLOW``,
so whoever can write the state directory cannot make the agent write a file elsewhere. A write
that fails (a full disk, a refused link) is logged, counted (``failures``, in every unit's
diag) and reported to ``on_outcome``: the unit's status then says its stop is not persisted,
until a retry (every ``RETRY_S``) writes it.

Writing happens on a ``latches`` thread of its own (a synced write takes milliseconds, and a
flood of stops must not make the safety thread wait on the disk): ``remember``/``forget`` only
record the newest state per unit (latest wins), the thread writes it, and ``close`` writes what
is left. The state directory: ``--state-dir``, else ``$D1_FLEET_STATE_DIR``, else
``$XDG_STATE_HOME/d1-fleet`` (``~/.local/state/d1-fleet``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

from fleet.files import FileReadError, read_regular
from fleet.guard import ThreadGuard
from fleet.wire import messages as m
from fleet.wire import payloads

log = logging.getLogger("edge_agent.latches")

MAX_LATCH_BYTES = 64 * 1024
"""A latched stop is one small StopRequest: a bigger file is refused (and latches anyway)."""
RETRY_S = 0.5
"""A latch the disk could not hold is written again this often until it is (or is reset)."""
_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
_NEW_FILE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC

Outcome = Callable[[str, "str | None"], None]
"""(unit, why its latch could not be written; None: the disk holds what the unit's latch is)."""


class LatchDirError(ValueError):
    """The latch directory cannot be used (a symbolic link, not a directory, not creatable)."""


def latch_dir(state_dir: Path, fleet: str, domain: int) -> Path:
    """Where the latched stops of ``fleet``'s units on DDS ``domain`` are kept."""
    return state_dir / fleet / f"domain-{domain}"


def _open_dir(name: str | Path, parent_fd: int | None, shown: Path) -> int:
    """The descriptor of directory ``name`` (in ``parent_fd``), created if absent; never
    through a symbolic link."""
    try:
        os.mkdir(name, 0o700, dir_fd=parent_fd)
    except FileExistsError:
        pass
    except OSError as exc:
        raise LatchDirError(
            f"{shown}: cannot create the latch directory ({exc.strerror})"
        ) from None
    try:
        return os.open(name, _DIR_FLAGS, dir_fd=parent_fd)
    except OSError as exc:
        raise LatchDirError(
            f"{shown}: not usable for latched stops ({exc.strerror}): it must be a real "
            "directory, not a symbolic link; remove it, or give the agent another --state-dir"
        ) from None


class LatchStore:
    """The latched stops of one fleet's units on one DDS domain, on disk."""

    def __init__(
        self,
        state_dir: Path,
        fleet: str,
        domain: int,
        guard: ThreadGuard,
        on_outcome: Outcome | None = None,
    ) -> None:
        self.directory = latch_dir(state_dir, fleet, domain)
        try:
            state_dir.mkdir(parents=True, exist_ok=True)
            base_fd = os.open(state_dir, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except OSError as exc:
            raise LatchDirError(f"{state_dir}: not usable for latched stops ({exc})") from None
        try:
            self._legacy_fd = _open_dir(fleet, base_fd, state_dir / fleet)
        finally:
            os.close(base_fd)
        try:
            self._fd = _open_dir(self.directory.name, self._legacy_fd, self.directory)
        except LatchDirError:
            os.close(self._legacy_fd)
            raise
        self._on_outcome = on_outcome if on_outcome is not None else (lambda _unit, _why: None)
        self.failures = 0
        """Latch writes and removals that failed (read by the diag without a lock: an int)."""
        self._lock = threading.Lock()
        self._pending: dict[str, m.StopRequest | None] = {}  # unit -> latched stop, None: reset
        self._unwritten: dict[str, m.StopRequest] = {}  # latches the disk could not hold yet
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._closed = False
        self.thread = guard.thread(self._run, "latches")

    def remember(self, unit: str, request: m.StopRequest) -> None:
        """``request`` is latched on ``unit`` (written soon, on the latches thread)."""
        with self._lock:
            self._pending[unit] = request
        self._wake.set()

    def forget(self, unit: str) -> None:
        """``unit`` was reset."""
        with self._lock:
            self._pending[unit] = None
        self._wake.set()

    def _run(self) -> None:
        while not self._closing.is_set():
            self._wake.wait(RETRY_S)
            self._wake.clear()
            self._write_pending()

    def _write_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, {}
            for unit, request in self._unwritten.items():  # tried again, unless superseded
                pending.setdefault(unit, request)
        for unit, request in pending.items():
            if request is None:
                self.clear(unit)
            else:
                self.save(unit, request)

    def close(self) -> None:
        """Stop the thread, write what is left, close the directories (idempotent)."""
        self._closing.set()
        self._wake.set()
        if self.thread.is_alive() and self.thread is not threading.current_thread():
            self.thread.join(timeout=2.0)
        if self._closed:
            return
        self._write_pending()
        self._closed = True
        os.close(self._fd)
        os.close(self._legacy_fd)

    @staticmethod
    def _name(unit: str) -> str:
        return f"{unit}.stop.json"

    def load(self, unit: str) -> m.StopRequest | None:
        """The stop latched on ``unit`` when its agent last ran, if any (an older agent's
        file is moved here once)."""
        data = self._read(unit, self._fd, self.directory)
        if data is None:
            data = self._read(unit, self._legacy_fd, self.directory.parent)
            if data is None:
                return None
            self._adopt(unit, data)
        if isinstance(data, m.StopRequest):
            return data
        try:
            return payloads.STOP.decode(data)
        except payloads.PayloadError as exc:
            return self._unreadable(unit, exc.why[:200])

    def _read(self, unit: str, dir_fd: int, shown: Path) -> bytes | m.StopRequest | None:
        """The latch file's bytes (None: no file), or the stop an unreadable one latches."""
        try:
            return read_regular(
                self._name(unit), MAX_LATCH_BYTES, "latch file", dir_fd=dir_fd, follow=False
            )
        except FileNotFoundError:
            return None
        except (FileReadError, OSError) as exc:
            return self._unreadable(unit, f"{shown}/{exc}")

    def _adopt(self, unit: str, data: bytes | m.StopRequest) -> None:
        """An older agent's latch file: written here, then removed there. Kept there when it
        is unreadable or the write failed: the next start reads it again, a reset removes it."""
        log.warning("%s: latched stop found in %s (an older agent's)", unit, self.directory.parent)
        if isinstance(data, bytes) and self._write(unit, data) is None:
            self._unlink(unit, self._legacy_fd)

    @staticmethod
    def _unreadable(unit: str, why: str) -> m.StopRequest:
        log.error("%s: its latched stop file is unreadable (%s): latched anyway", unit, why)
        return m.StopRequest(
            stamp_ns=time.time_ns(),
            source="edge-agent",
            stop_id=f"unreadable-latch-{unit}-{time.time_ns()}",
            reason=f"latched before a restart; the latch file was unreadable ({why})",
        )

    def save(self, unit: str, request: m.StopRequest) -> None:
        """Remember that ``request`` is latched on ``unit`` (atomic, synced); a failure is
        counted and reported."""
        why = self._write(unit, m.encode(request))
        with self._lock:
            again = self._unwritten.get(unit) == request
            if why is None:
                self._unwritten.pop(unit, None)
            else:
                self._unwritten[unit] = request
        if why is not None and not again:  # counted and logged once per stop, not per retry
            self.failures += 1
            log.error("%s: could not persist its latched stop (%s); retrying", unit, why)
        self._on_outcome(unit, why)

    def _write(self, unit: str, data: bytes) -> str | None:
        """Write ``data`` as ``unit``'s latch file; None, or why it failed."""
        temporary = f"{unit}.stop.tmp"
        try:
            # A stale temporary (or a link planted in its place) goes first; then O_EXCL and
            # O_NOFOLLOW: the file written is always a new one in this directory.
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temporary, dir_fd=self._fd)
            fd = os.open(temporary, _NEW_FILE_FLAGS, 0o600, dir_fd=self._fd)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                os.fsync(fd)
            finally:
                os.close(fd)
            # rename replaces a link at the final name, never what it points to
            os.replace(temporary, self._name(unit), src_dir_fd=self._fd, dst_dir_fd=self._fd)
            os.fsync(self._fd)  # the rename itself is on disk
        except OSError as exc:
            return f"{self.directory / self._name(unit)}: {exc.strerror or exc}"
        return None

    def clear(self, unit: str) -> None:
        """``unit`` was reset: its file goes, and an older agent's (a failure is counted: a
        restart would latch the unit again, the safe side)."""
        with self._lock:
            self._unwritten.pop(unit, None)
        self._unlink(unit, self._fd)
        self._unlink(unit, self._legacy_fd)
        self._on_outcome(unit, None)

    def _unlink(self, unit: str, dir_fd: int) -> None:
        try:
            os.unlink(self._name(unit), dir_fd=dir_fd)
        except FileNotFoundError:
            return
        except OSError as exc:
            self.failures += 1
            log.error("%s: could not remove its latched stop file (%s)", unit, exc)
