"""Files a running process reads, read so that no file can freeze or flood it.

A calibration file replaced by a named pipe blocked the agent's relay thread on ``read()``: the
agent still looked "up" but relayed nothing, and a stop 0.8 s later found no fresh pose. So:

- ``read_regular`` opens without blocking (``O_NONBLOCK``: opening a FIFO returns at once),
  refuses anything that is not a regular file (``fstat`` of the open descriptor: no race with a
  swap after a ``stat``), and reads at most ``max_bytes`` (a bigger file is refused, not
  truncated). A regular file on a hung network or FUSE mount can still block: hence
- ``FileWatcher``: the reads happen on a thread of their own, never on a safety or relay path;
  the result is handed over under a lock. ``stuck_s`` says how long the current read has taken:
  the process's watchdog (the agent's relay tick) fails the process through its ``ThreadGuard``
  when it passes ``FILE_TIMEOUT_S`` (the agent then latches every arm and exits, as for any failed
  thread; a supervisor restarts it).
"""

from __future__ import annotations

import errno
import math
import os
import stat
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO, Generic, TypeVar

T = TypeVar("T")

MAX_FILE_BYTES = 1 << 20
"""The default cap: every file a running process reads (calibration, inventory, latches) is
far smaller."""
FILE_TIMEOUT_S = 5.0
"""A read that takes longer than this fails the process (a hung mount, a stalled disk)."""


class FileReadError(ValueError):
    """A file that was refused (its path and why in the message)."""


def _open_regular_fd(
    path: str | Path, what: str, dir_fd: int | None = None, follow: bool = True
) -> tuple[int, os.stat_result]:
    """A descriptor of ``path`` (relative to ``dir_fd`` if given) opened without blocking, and
    its ``fstat``, if it is a regular file; with ``follow`` False a symbolic link is refused.
    Raises FileNotFoundError when absent, FileReadError for anything else refused."""
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow else os.O_NOFOLLOW)
    try:
        fd = os.open(path, flags, dir_fd=dir_fd)
    except FileNotFoundError:
        raise
    except OSError as exc:
        if exc.errno == errno.ELOOP and not follow:
            raise FileReadError(f"{path}: the {what} is a symbolic link; refused") from None
        raise FileReadError(f"{path}: cannot open the {what} ({exc.strerror})") from None
    try:
        info = os.fstat(fd)
    except OSError as exc:
        os.close(fd)
        raise FileReadError(f"{path}: cannot read the {what} ({exc.strerror})") from None
    if not stat.S_ISREG(info.st_mode):
        os.close(fd)
        raise FileReadError(f"{path}: the {what} is not a regular file; refused")
    return fd, info


def open_regular(path: str | Path, max_bytes: int, what: str = "file") -> BinaryIO:
    """``path`` opened for reading (a buffered binary file) if it is a regular file of at most
    ``max_bytes``: for files read piece by piece (recordings), whose reader bounds what it
    keeps. Raises FileNotFoundError when absent, FileReadError for anything else refused."""
    fd, info = _open_regular_fd(path, what)
    if info.st_size > max_bytes:
        os.close(fd)
        raise FileReadError(
            f"{path}: the {what} is {info.st_size} bytes, more than {max_bytes}; refused"
        )
    os.set_blocking(fd, True)  # a regular file: reads are whole again, never EAGAIN
    return os.fdopen(fd, "rb")


def read_regular(
    path: str | Path,
    max_bytes: int = MAX_FILE_BYTES,
    what: str = "file",
    *,
    dir_fd: int | None = None,
    follow: bool = True,
) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``max_bytes``. Raises
    FileNotFoundError when absent, FileReadError for anything else refused. ``dir_fd`` and
    ``follow`` as for ``_open_regular_fd``."""
    fd, info = _open_regular_fd(path, what, dir_fd, follow)
    try:
        if info.st_size > max_bytes:
            raise FileReadError(
                f"{path}: the {what} is {info.st_size} bytes, more than {max_bytes}; refused"
            )
        chunks, total = [], 0
        while total <= max_bytes:
            chunk = os.read(fd, min(65536, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > max_bytes:
            raise FileReadError(f"{path}: the {what} grew past {max_bytes} bytes; refused")
        return b"".join(chunks)
    except OSError as exc:
        raise FileReadError(f"{path}: cannot read the {what} ({exc.strerror})") from None
    finally:
        os.close(fd)


def file_stamp(path: Path | None) -> tuple[float, int, int] | None:
    """(mtime, size, inode) of ``path``, None when absent or unreadable. ``os.stat`` never
    opens the file: a FIFO does not block it."""
    if path is None:
        return None
    try:
        info = path.stat()
    except OSError:
        return None
    return (info.st_mtime, info.st_size, info.st_ino)


def plausible(value: float, lo: float, hi: float) -> bool:
    """True when ``value`` is finite and within [lo, hi]."""
    return math.isfinite(value) and lo <= value <= hi


class FileWatcher(Generic[T]):
    """Calls ``poll`` (which reads files) every ``period_s`` on its own thread and keeps its
    latest result for ``take``; ``stuck_s`` is how long the current poll has run."""

    def __init__(
        self,
        poll: Callable[[], T | None],
        period_s: float,
        stopping: threading.Event,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._poll = poll
        self._period_s = period_s
        self._stopping = stopping
        self._clock = clock
        self._lock = threading.Lock()  # guards _result and _busy_since
        self._result: T | None = None
        self._busy_since: float | None = None

    def run(self) -> None:
        """The thread's body (run it under the process's guard)."""
        while not self._stopping.is_set():
            with self._lock:
                self._busy_since = self._clock()
            result = self._poll()
            with self._lock:
                self._busy_since = None
                if result is not None:
                    self._result = result
            self._stopping.wait(self._period_s)

    def take(self) -> T | None:
        """The newest result not taken yet (None: nothing new)."""
        with self._lock:
            result, self._result = self._result, None
        return result

    def stuck_s(self, now: float | None = None) -> float:
        """How long the poll running now has taken (0 when none runs)."""
        with self._lock:
            since = self._busy_since
        return 0.0 if since is None else (self._clock() if now is None else now) - since
