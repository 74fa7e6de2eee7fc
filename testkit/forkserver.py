"""A fork server for the tests' fleet processes: each process starts with the fleet imported.

The suite starts about 600 routers, simulators, agents and coordinators. Each one paid for a
Python interpreter and the fleet's imports (CycloneDDS, Zenoh, msgspec: 0.3-0.4 CPU-s) before
doing anything, on a 2-core machine that the suite keeps busy. This server imports them once
per pytest worker, then forks a child per process: the child is still a process of its own
(its own PID, DDS participant, Zenoh session, signals, exit code, log file), running the same
``python -m <module>`` code path with the given argv, environment and working directory.

Fork safety: the server starts no thread and opens no session or DDS entity, so a child
inherits nothing but imported modules (``tests/unit/test_forkserver.py`` checks the thread
count after the imports). ``TEST_FORK_SERVER=0`` starts every process the classic way.

Protocol, JSON lines: requests on the server's stdin (``argv``, ``log``, ``env``, ``cwd``,
``nice``: the calling thread's nice value, which a Popen child would inherit);
answers on its stdout: ``{"started": pid}`` once per request in order, and ``{"exited": pid,
"code": n}`` (``code`` as ``Popen.returncode``: negative for a signal) when a child ends.

A child that ended stays a zombie until the client has its code and sends ``{"release": pid}``:
as with Popen, whose parent reaps only in ``poll``/``wait``, a PID the client may still signal
is never free for the kernel to give to another process (and a signal to it is never ESRCH).
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import json
import os
import runpy
import selectors
import signal
import subprocess
import sys
import threading
from typing import Any

PRELOAD = (
    "edge_agent.__main__",
    "edge_agent.metrics",
    "fleet.cli.main",
    "fleet.sim.node",
    "fleet.sim.devices",
    "fleet.sim.metrics",
    "fleet.coordinator.service",
    "fleet.coordinator.metrics",
)
"""The modules the harness's processes import: the router, simulator, agent and coordinator."""
ENABLED_ENV = "TEST_FORK_SERVER"


# ---------------------------------------------------------------------------------- server


def _serve() -> dict[str, Any] | None:
    """Fork a child per request. Returns in a child (its request) or None at end of input."""
    for name in PRELOAD:
        __import__(name)
    answers = os.dup(1)
    wake_read, wake_write = os.pipe()
    os.set_blocking(wake_write, False)
    signal.set_wakeup_fd(wake_write)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    selector = selectors.DefaultSelector()
    selector.register(0, selectors.EVENT_READ)
    selector.register(wake_read, selectors.EVENT_READ)
    pending = b""
    running: set[int] = set()
    while True:
        for key, _ in selector.select(timeout=1.0):
            if key.fd == wake_read:
                os.read(wake_read, 4096)
                continue
            data = os.read(0, 65536)
            if not data:
                return None
            pending += data
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                request = json.loads(line)
                if "release" in request:
                    _release(request["release"])
                    continue
                pid = os.fork()
                if pid == 0:
                    selector.close()
                    for fd in (answers, wake_read, wake_write):
                        os.close(fd)
                    return request  # type: ignore[no-any-return]
                running.add(pid)
                _answer(answers, {"started": pid})
        _report_exits(answers, running)


def _report_exits(answers: int, running: set[int]) -> None:
    """Answer for each child that ended, leaving it a zombie (WNOWAIT) until released."""
    for pid in list(running):
        ended = os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        if ended is None or ended.si_pid == 0:
            continue
        running.discard(pid)
        killed = ended.si_code in (os.CLD_KILLED, os.CLD_DUMPED)
        _answer(answers, {"exited": pid, "code": -ended.si_status if killed else ended.si_status})


def _release(pid: int) -> None:
    with contextlib.suppress(ChildProcessError):
        os.waitpid(pid, 0)  # a zombie: returns at once


def _answer(fd: int, message: dict[str, int]) -> None:
    os.write(fd, json.dumps(message).encode() + b"\n")


def _become(request: dict[str, Any]) -> None:
    """Turn this forked child into ``python -m <module> args...`` as Popen would start it."""
    signal.set_wakeup_fd(-1)
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    os.chdir(request["cwd"])
    # The worker's nice value of the moment (testkit.priority), as a Popen child inherits it;
    # lower than the server's needs root, elsewhere it stays.
    with contextlib.suppress(PermissionError):
        os.setpriority(os.PRIO_PROCESS, 0, request["nice"])
    os.environ.clear()
    os.environ.update(request["env"])
    null = os.open(os.devnull, os.O_RDONLY)
    log = os.open(request["log"], os.O_WRONLY | os.O_APPEND)
    os.dup2(null, 0)
    os.dup2(log, 1)
    os.dup2(log, 2)
    os.close(null)
    os.close(log)
    argv = request["argv"]
    _name_thread(argv[1])
    sys.argv = [argv[1], *argv[2:]]  # run_module puts the module's path in argv[0]
    runpy.run_module(argv[1], run_name="__main__", alter_sys=True)


def _name_thread(module: str) -> None:
    """``ps -o comm``/``top`` show the module, not the server (its cmdline stays the
    server's)."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(15, module.encode()[-15:], 0, 0, 0)  # PR_SET_NAME


def main() -> None:
    request = _serve()
    if request is not None:
        _become(request)  # SystemExit from the module ends the child with its code


# ---------------------------------------------------------------------------------- client


class ForkedProcess:
    """A process the server forked: what the harness uses of ``subprocess.Popen``."""

    def __init__(self, server: ForkServer, pid: int, args: list[str]) -> None:
        self._server = server
        self.pid = pid
        self.args = args
        self.returncode: int | None = None

    def poll(self) -> int | None:
        return self._collect(0.0)

    def wait(self, timeout: float | None = None) -> int:
        code = self._collect(timeout)
        if code is None:
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        return code

    def _collect(self, timeout: float | None) -> int | None:
        """The exit code once known; the server then reaps the child (Popen reaps in poll)."""
        if self.returncode is None:
            self.returncode = self._server.exit_code(self.pid, timeout)
            if self.returncode is not None:
                self._server.release(self.pid)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        # Until released, an ended child is an unreaped zombie: its PID is still ours.
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):  # the server died and init reaped it
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class ForkServer:
    """One server per pytest worker, started on first use and ended with the worker."""

    def __init__(self) -> None:
        self._process = subprocess.Popen(
            [sys.executable, "-m", "testkit.forkserver"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        self._lock = threading.Lock()  # one request and its answer at a time
        self._changed = threading.Condition()
        self._started: list[int] = []
        self._codes: dict[int, int] = {}
        threading.Thread(target=self._read_answers, name="forkserver", daemon=True).start()
        atexit.register(self.close)

    def start(self, argv: list[str], log: str, env: dict[str, str]) -> ForkedProcess:
        """Fork ``python argv...`` (argv = ["-m", module, ...]) with output appended to ``log``."""
        request = {
            "argv": argv,
            "log": log,
            "env": env,
            "cwd": os.getcwd(),
            "nice": os.getpriority(os.PRIO_PROCESS, 0),
        }
        assert self._process.stdin is not None
        with self._lock:
            # Written outside the condition: the reader thread must never wait on it for a
            # write that waits on the server.
            self._process.stdin.write(json.dumps(request).encode() + b"\n")
            self._process.stdin.flush()
            with self._changed:
                if not self._changed.wait_for(lambda: self._started or not self.alive(), 30.0):
                    raise RuntimeError("the fork server did not answer within 30 s")
                if not self._started:
                    raise RuntimeError(f"the fork server exited ({self._process.poll()})")
                pid = self._started.pop(0)
        return ForkedProcess(self, pid, [sys.executable, *argv])

    def exit_code(self, pid: int, timeout: float | None) -> int | None:
        with self._changed:
            self._changed.wait_for(lambda: pid in self._codes or not self.alive(), timeout)
            return self._codes.get(pid)

    def release(self, pid: int) -> None:
        """Let the server reap ``pid``, whose code the client now has."""
        assert self._process.stdin is not None
        with self._lock, contextlib.suppress(BrokenPipeError, ValueError):
            self._process.stdin.write(json.dumps({"release": pid}).encode() + b"\n")
            self._process.stdin.flush()
        with self._changed:
            self._codes.pop(pid, None)

    def alive(self) -> bool:
        return self._process.poll() is None

    def _read_answers(self) -> None:
        assert self._process.stdout is not None
        for line in self._process.stdout:
            answer = json.loads(line)
            with self._changed:
                if "started" in answer:
                    self._started.append(answer["started"])
                else:
                    self._codes[answer["exited"]] = answer["code"]
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    def close(self) -> None:
        """End the server (its input closes); children it forked keep running."""
        if self._process.stdin is not None and not self._process.stdin.closed:
            self._process.stdin.close()
        try:
            self._process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()


_server: ForkServer | None = None
_server_lock = threading.Lock()


def fork_server() -> ForkServer | None:
    """This worker's server, started on first use; None when ``TEST_FORK_SERVER=0``."""
    global _server
    if os.environ.get(ENABLED_ENV, "1") == "0":
        return None
    with _server_lock:
        if _server is None or not _server.alive():
            _server = ForkServer()
        return _server


if __name__ == "__main__":
    main()
