"""One guard for every thread of a long-running process.

A thread that dies must take its process down safely, not leave a zombie that looks healthy (an
agent with ``link=ok`` whose stop handling is gone; a coordinator whose heartbeat goes on while
its event thread is dead). So every thread body, timer, pool task and Zenoh callback of a process
runs through one ``ThreadGuard``: an unexpected exception is logged with the thread's name, the
process's ``on_failure`` runs once (the agent latches and holds every arm it serves; the
coordinator stops its heartbeat), and ``failed`` is set; the main thread sees it and exits
non-zero, so a supervisor restarts the process.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import threading
from collections.abc import Callable
from typing import ParamSpec, TypeVar

P = ParamSpec("P")
R = TypeVar("R")

log = logging.getLogger("fleet.guard")

EXIT_THREAD_FAILED = 1
"""The exit code of a process whose thread failed (it shut down safely; restart it)."""


_PR_SET_NAME = 15
_libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)


def name_native_thread(name: str) -> None:
    """Give the calling OS thread ``name`` (15 bytes at most) so ``top -H`` and /proc's per-thread
    CPU say which of our threads is which, not ``python`` eight times."""
    _libc.prctl(_PR_SET_NAME, name.encode()[:15], 0, 0, 0)


class ThreadGuard:
    """Wraps thread bodies and callbacks; ``failed`` is set by the first unexpected failure."""

    def __init__(self, process: str, on_failure: Callable[[str], None] | None = None) -> None:
        self.process = process
        self.failed = threading.Event()
        self.failure: str | None = None
        self._on_failure = on_failure
        self._lock = threading.Lock()

    def thread(self, target: Callable[[], object], name: str) -> threading.Thread:
        """A daemon thread (not started) whose body runs under the guard, named ``name`` for the
        OS too."""
        body = self.wrap(target, name)

        def named() -> None:
            name_native_thread(name)
            body()

        return threading.Thread(target=named, name=name, daemon=True)

    def wrap(self, fn: Callable[P, R], name: str | None = None) -> Callable[P, R | None]:
        """``fn`` under the guard: an exception is reported (``fail``) and not re-raised, so a
        Zenoh callback or a pool never swallows it silently."""

        def guarded(*args: P.args, **kwargs: P.kwargs) -> R | None:
            try:
                return fn(*args, **kwargs)
            except BaseException as exc:  # noqa: BLE001 - the guard's whole purpose
                self.fail(name or threading.current_thread().name, exc)
                return None

        return guarded

    def fail(self, where: str, exc: BaseException | None = None) -> None:
        """Report a failure of ``where``: log, run ``on_failure`` once, set ``failed``."""
        if exc is not None:
            log.critical(
                "%s: %s failed: %s: %s; shutting down safely",
                self.process,
                where,
                type(exc).__name__,
                exc,
                exc_info=exc,
            )
        with self._lock:
            first = self.failure is None
            if first:
                self.failure = f"{where}: {type(exc).__name__ if exc else 'failed'}: {exc or ''}"
        if not first:
            return
        # On a thread of its own: the failing thread may be a Zenoh callback (publishing from
        # there can deadlock the session) or hold state the handler needs.
        handler = threading.Thread(target=self._handle, name="guard-failure", daemon=True)
        handler.start()

    def _handle(self) -> None:
        try:
            if self._on_failure is not None:
                self._on_failure(self.failure or "unknown")
        except BaseException:  # noqa: BLE001 - the failure path must reach `failed`
            log.exception("%s: the failure handler failed too", self.process)
        finally:
            self.failed.set()
