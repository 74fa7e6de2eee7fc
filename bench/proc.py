"""Process plumbing of the benchmark: a loopback fleet of real processes, stopped by PID.

Every process is started with ``subprocess`` and ``sys.executable`` (fork + exec: nothing of this
process's state reaches a child), opens DDS or Zenoh itself, and is stopped by its PID when the
``BenchFleet`` closes (SIGTERM, then SIGKILL after a bounded wait). Workers of ``bench/`` speak a
tiny protocol on their pipes: they print ``READY`` once their entities exist, run until their
stdin is closed (or their own time limit), then print one JSON line with their results.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from testkit.harness import claim_domain, free_port, inventory_text

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
PAGE_KB = os.sysconf("SC_PAGE_SIZE") // 1024
FLEET = "bench"
REPO = Path(__file__).resolve().parent.parent


def cpu_s(pid: int) -> float:
    """utime + stime of ``pid`` (all its threads) in seconds, from /proc/<pid>/stat."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def rss_mb(pid: int) -> float:
    """Resident set size of ``pid`` in MiB, from /proc/<pid>/statm."""
    pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
    return pages * PAGE_KB / 1024.0


class Worker:
    """One child process with the READY / stdin-close / JSON-line protocol (or a plain one)."""

    def __init__(self, name: str, argv: list[str], log_dir: Path, piped: bool) -> None:
        self.name = name
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.piped = piped
        self.process = subprocess.Popen(
            [sys.executable, *argv],
            stdin=subprocess.PIPE if piped else subprocess.DEVNULL,
            stdout=subprocess.PIPE if piped else self._log,
            stderr=self._log,
            env={
                **os.environ,
                "PYTHONUNBUFFERED": "1",
                "PYTHONPATH": str(REPO),
                "D1_FLEET_STATE_DIR": str(log_dir / "state"),  # latches stay in the run
            },
            cwd=REPO,
            text=True,
        )
        self.pid = self.process.pid

    def _stdout(self) -> IO[str]:
        assert self.process.stdout is not None, f"{self.name} has no pipe"
        return self.process.stdout

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        """Block until the worker printed READY (its entities exist); RuntimeError otherwise."""
        self._read_until(lambda line: line == "READY", timeout_s)

    def _read_until(self, accept: Callable[[str], bool], timeout_s: float) -> str:
        """The first stdout line ``accept`` takes (other lines, e.g. a library's, are skipped)."""
        stdout = self._stdout()
        deadline = time.monotonic() + timeout_s
        with selectors.DefaultSelector() as sel:
            sel.register(stdout, selectors.EVENT_READ)
            while True:
                left = deadline - time.monotonic()
                if left <= 0 or not sel.select(left):
                    raise RuntimeError(
                        f"{self.name}: no answer in {timeout_s} s\n{self.log_tail()}"
                    )
                line = stdout.readline()
                if not line:
                    raise RuntimeError(f"{self.name} ended early\n{self.log_tail()}")
                if accept(line.strip()):
                    return line

    def finish(self, timeout_s: float = 60.0) -> dict[str, Any]:
        """Close stdin (the worker's signal to stop) and read its JSON result."""
        assert self.process.stdin is not None
        self.process.stdin.close()
        return self.result(timeout_s)

    def result(self, timeout_s: float) -> dict[str, Any]:
        """Read the worker's JSON result line (it prints one when it is done)."""
        line = self._read_until(lambda text: text.startswith("{"), timeout_s)
        result: dict[str, Any] = json.loads(line)
        return result

    def wait_log(self, needle: str, timeout_s: float) -> str:
        """Block until a line of the worker's log holds ``needle`` (a plain process's own
        announcement, e.g. the viewer's URL); returns that line. RuntimeError otherwise."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and self.alive():
            self._log.flush()
            for line in self.log_path.read_text(errors="replace").splitlines():
                if needle in line:
                    return line
            time.sleep(0.2)
        raise RuntimeError(f"{self.name}: no {needle!r} in {timeout_s} s\n{self.log_tail()}")

    def log_tail(self, lines: int = 20) -> str:
        """The end of the worker's stderr log."""
        self._log.flush()
        text = self.log_path.read_text(errors="replace").splitlines()
        return "\n".join(text[-lines:])

    def alive(self) -> bool:
        """True while the process runs."""
        return self.process.poll() is None

    def stop(self, timeout_s: float = 10.0) -> None:
        """SIGTERM by PID, SIGKILL after ``timeout_s`` (idempotent)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=timeout_s)
        for pipe in (self.process.stdin, self.process.stdout):
            if pipe is not None and not pipe.closed:
                pipe.close()
        self._log.close()


DATAGRAM_ENV = "BENCH_DATAGRAM"
"""``BENCH_DATAGRAM=0``: every bench fleet without the stops' datagram path (``[zenoh] datagram
= false``), to measure what the path costs the relay and the commands."""


class BenchFleet:
    """A router on a free port, a DDS domain of our own and an inventory of ``arms`` simulated
    arms (a1.., suffixes _1..; ``extra``: more inventory text, e.g. devices), plus every
    process started for one measurement."""

    def __init__(self, arms: int, tag: str, extra: str = "") -> None:
        self._tmp = tempfile.TemporaryDirectory(prefix=f"d1-bench-{tag}-")
        self.dir = Path(self._tmp.name)
        self.port = free_port()
        self.domain, self._domain_lock = claim_domain()
        self.arms = [f"a{i}" for i in range(1, arms + 1)]
        self.inventory = self.dir / "inventory.toml"
        # An inventory needs one arm at least, even for the raw measurements that use none.
        text = inventory_text(FLEET, self.port, self.domain, max(1, arms), extra)
        if os.environ.get(DATAGRAM_ENV) == "0":  # the stops' datagram path off, to compare
            text = text.replace("[zenoh]\n", "[zenoh]\ndatagram = false\n", 1)
        self.inventory.write_text(text, encoding="utf-8")
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.workers: list[Worker] = []

    def start(
        self, name: str, argv: list[str], piped: bool = False, log_level: str = "WARNING"
    ) -> Worker:
        """Start ``python argv... --inventory ...`` (a bench worker when ``piped``)."""
        common = ["--inventory", str(self.inventory), "--log-level", log_level]
        worker = Worker(name, [*argv, *common], self.dir, piped)
        self.workers.append(worker)
        return worker

    def start_router(
        self, name: str = "router", port: int | None = None, connect: tuple[str, ...] = ()
    ) -> Worker:
        """``fleet router`` on the inventory's endpoint, or listening on ``port`` and joined to
        the routers at ``connect`` (a site router); returns once it accepts connections."""
        port = self.port if port is None else port
        argv = ["-m", "fleet.cli.main", "router"]
        if port != self.port:
            argv += ["--listen", f"tcp/127.0.0.1:{port}"]
        for endpoint in connect:
            argv += ["--connect", endpoint]
        router = self.start(name, argv)
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and router.alive():
            with socket.socket() as probe:
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    return router
            time.sleep(0.05)
        raise RuntimeError(f"{name} did not listen on port {port}\n{router.log_tail()}")

    def groups(self, size: int) -> list[list[str]]:
        """The arms in consecutive groups of ``size`` (one agent, or one simulator, each)."""
        return [self.arms[i : i + size] for i in range(0, len(self.arms), size)]

    def arm_args(self, arms: list[str]) -> list[str]:
        """``--arm a1 --arm a2 ...``."""
        return [x for a in arms for x in ("--arm", a)]

    def close(self) -> None:
        """Stop every process by PID, newest first, then release the domain and files."""
        for worker in reversed(self.workers):
            worker.stop()
        self.workers.clear()
        self._domain_lock.close()
        self._tmp.cleanup()

    def __enter__(self) -> BenchFleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
