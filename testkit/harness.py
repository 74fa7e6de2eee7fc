"""Test harness: a fleet of real processes on loopback, isolated per test.

Each ``FleetHarness`` gets a DDS domain id and a Zenoh port of its own, writes an inventory for
them, starts the router, simulated arms, agents (and whatever else a test needs) as separate
processes, and stops every process it started by PID. Waits are bounded: ``wait_until``.
"""

from __future__ import annotations

import contextlib
import fcntl
import itertools
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, TypeVar

from fleet.client import FleetClient
from fleet.d1.dds import MAX_PARTICIPANTS_PER_HOST
from fleet.inventory import Inventory, load_inventory
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.forkserver import ForkedProcess, fork_server

T = TypeVar("T")
Process = subprocess.Popen[bytes] | ForkedProcess
"""A process the harness started: Popen's, or the fork server's (``testkit.forkserver``)."""

# Domains 1..99 keep CycloneDDS's ports (7400 + 250 * domain ...) below the ephemeral range that
# free Zenoh ports come from. The run's PID spreads parallel runs; the counter separates tests.
_domains = itertools.count((os.getpid() * 7) % 90)
_DOMAIN_LOCKS = Path(tempfile.gettempdir()) / "d1-fleet-test-domains"


def _domain_in_use(domain: int) -> bool:
    """True when some participant on this host holds a discovery port of ``domain``.

    CycloneDDS's unicast discovery port of participant index i is 7400 + 250 * domain + 10 + 2i;
    a demo or another test run on the same host (the domain of a `fleet demo` is random) would
    otherwise cross-talk with this test's arms.
    """
    for index in range(MAX_PARTICIPANTS_PER_HOST + 1):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("0.0.0.0", 7400 + 250 * domain + 10 + 2 * index))
            except OSError:
                return True
    return False


def _reserve(locks: Path, number: int, in_use: Callable[[int], bool]) -> IO[bytes] | None:
    """The lock file that reserves ``number`` (a domain, a port) against other test processes
    until closed (the OS drops it if the process dies), or None when another holds it or
    ``in_use`` says something else uses it."""
    locks.mkdir(exist_ok=True)
    lock = open(locks / f"{number}.lock", "wb")  # noqa: SIM115 - held until close
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        return None
    if in_use(number):
        lock.close()
        return None
    return lock


def claim_domain() -> tuple[int, IO[bytes]]:
    """A DDS domain id no other process of this host uses, with the lock file that reserves it
    against other test runs until closed (the OS drops the lock if the run dies)."""
    for _ in range(99):
        domain = 1 + next(_domains) % 99
        lock = _reserve(_DOMAIN_LOCKS, domain, _domain_in_use)
        if lock is not None:
            return domain, lock
    raise RuntimeError("every DDS domain 1..99 is in use on this host")


@contextlib.contextmanager
def reserved_domain() -> Iterator[int]:
    """``claim_domain`` for a block: a test that starts its own DDS processes (a demo) holds
    its domain against every other test process of the host until the block ends. (A domain
    only counted, never reserved, was once taken by a harness of another pytest worker at the
    same time: two fleets' arms on one domain.)"""
    domain, lock = claim_domain()
    try:
        yield domain
    finally:
        lock.close()


_PORT_LOCKS = Path(tempfile.gettempdir()) / "d1-fleet-test-ports"
_held_ports: dict[int, IO[bytes]] = {}


def _test_ports() -> range:
    """The ports tests listen on: above the kernel's ephemeral range (32768-60999 here), so
    that none is taken meanwhile as the local port of some process's outgoing socket (a
    datagram session's UDP socket, a client's TCP connection). Measured: a test's router found
    the ephemeral port it had been given so taken ("in use") in a fresh-clone run. Below
    32768 are the DDS domains' ports. Where the ephemeral range reaches the top, none."""
    try:
        _low, high = map(int, Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    except (OSError, ValueError):
        return range(0)
    return range(high + 1, 65536) if high < 65000 else range(0)


_ports = itertools.count(os.getpid() * 13)


def _bindable(port: int) -> bool:
    """True when nothing holds ``port`` on 127.0.0.1, TCP or UDP (a router takes both)."""
    for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
        with socket.socket(socket.AF_INET, kind) as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def free_port() -> int:
    """A port on 127.0.0.1 free for TCP and UDP right now, outside the ephemeral range, and
    reserved against this run's other workers and other runs by a lock file until
    ``release_port`` (or this process's end). Where no such range exists, an ephemeral one."""
    ports = _test_ports()
    for _ in range(len(ports)):
        port = ports[next(_ports) % len(ports)]
        if port in _held_ports:
            continue
        lock = _reserve(_PORT_LOCKS, port, lambda p: not _bindable(p))
        if lock is not None:
            _held_ports[port] = lock
            return port
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def release_port(port: int) -> None:
    """Let other tests have ``port`` again (its user stopped listening)."""
    lock = _held_ports.pop(port, None)
    if lock is not None:
        lock.close()


HUNG_AT_SHUTDOWN = re.compile(r"^Timeout \(\d+:\d\d:\d\d(\.\d+)?\)!$", re.MULTILINE)
"""What a process prints when its shutdown outlasted ``fleet.runtime.SHUTDOWN_BOUND_S`` (its
threads' stacks follow)."""


def wait_until(
    predicate: Callable[[], T],
    timeout_s: float,
    interval_s: float = 0.05,
    explain: Callable[[], str] | None = None,
) -> T:
    """Poll ``predicate`` until it returns something truthy; AssertionError after ``timeout_s``,
    with what ``explain()`` then says (the state a failure is diagnosed from)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() >= deadline:
            why = f"\n{explain()}" if explain is not None else ""
            raise AssertionError(f"condition not met within {timeout_s} s: {predicate}{why}")
        time.sleep(interval_s)


def next_diag(client: FleetClient, fleet: str, arm: str) -> m.Diag:
    """The arm's next diag (the agent publishes it every second)."""
    subscriber = client.session.declare_subscriber(keys.KeySpace(fleet).arm(arm, keys.DIAG))
    try:
        sample = wait_until(subscriber.try_recv, 5.0)
    finally:
        subscriber.undeclare()
    return payloads.DIAG.decode(sample.payload.to_bytes())


def inventory_text(
    fleet: str, port: int, domain: int, arms: int = 1, extra: str = "", security: str = "none"
) -> str:
    """An inventory of ``arms`` simulated arms (a1.. with suffixes _1..) on loopback; with
    ``security`` ``mtls`` or ``password``, TLS endpoints and certificates in ``certs/``."""
    scheme = "tcp" if security == "none" else "tls"
    lines = [
        f'[fleet]\nname = "{fleet}"\n',
        f'[zenoh]\nendpoints = ["{scheme}/127.0.0.1:{port}"]\n',
        f'[security]\nmode = "{security}"\n',
        f'[dds]\ndomain_id = {domain}\npeers = ["127.0.0.1"]\n',
        '[defaults]\ninterface = "lo"\nsimulated = true\n'
        # One agent process serves every arm in tests: one identity for all of them.
        + ('agent = "agent-lo"\n' if security != "none" else ""),
    ]
    for i in range(1, arms + 1):
        lines.append(f'[arms.a{i}]\nsuffix = "_{i}"\nbase_xyz = [0.0, {0.6 * (i - 1):.1f}, 0.0]\n')
    lines.append(extra)
    return "\n".join(lines)


class FleetHarness:
    """Processes of one test's fleet. Use as a context manager (the fixture does)."""

    def __init__(
        self, tmp_path: Path, arms: int = 1, extra: str = "", security: str = "none"
    ) -> None:
        self.tmp_path = tmp_path
        self.port = free_port()
        self.domain, self._domain_lock = claim_domain()
        scheme = "tcp" if security == "none" else "tls"
        self.endpoint = f"{scheme}/127.0.0.1:{self.port}"
        self.inventory_path = tmp_path / "inventory.toml"
        self.inventory_path.write_text(
            inventory_text("test", self.port, self.domain, arms, extra, security),
            encoding="utf-8",
        )
        self.inventory: Inventory = load_inventory(self.inventory_path)
        if security != "none":
            from fleet.security.certs import make_certs

            make_certs(self.inventory, self.inventory.security.certs, days=2)
        self.killed: list[str] = []
        """Processes that had to be killed: they did not stop on their signal."""
        self.processes: dict[str, Process] = {}
        self._logs: dict[str, Path] = {}
        self._clients: list[FleetClient] = []

    # ------------------------------------------------------------------ processes

    def start(
        self, name: str, argv: list[str], prefix: tuple[str, ...] = (), inventory: bool = True
    ) -> Process:
        """Start ``[prefix] python argv...`` with the inventory option appended (unless
        ``inventory`` is False); output to a log file. ``prefix`` runs it through another
        command, e.g. ``ip netns exec <ns>``. A ``-m module`` without a prefix is forked by the
        worker's fork server, with the fleet already imported."""
        log_path = self.tmp_path / f"{name}.log"
        if log_path.exists():  # a restart: the previous run's output is kept beside it
            log_path.replace(log_path.with_suffix(".log.1"))
        self._logs[name] = log_path
        argv = [*argv, *(["--inventory", str(self.inventory_path)] if inventory else [])]
        # Latched stops persist per test, never in the user's state directory.
        env = {
            **os.environ,
            "PYTHONUNBUFFERED": "1",
            "D1_FLEET_STATE_DIR": str(self.tmp_path / "state"),
        }
        server = fork_server() if not prefix and argv[0] == "-m" else None
        process: Process
        if server is not None:
            log_path.write_bytes(b"")
            process = server.start(argv, str(log_path), env)
        else:
            with open(log_path, "wb") as log:
                process = subprocess.Popen(
                    [*prefix, sys.executable, *argv],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=env,
                )
        self.processes[name] = process
        return process

    def start_router(self, *options: str, wait: bool = True) -> Process:
        """``fleet router [options]``; returns once the port accepts connections (with
        ``wait`` False at once: ``wait_router`` later)."""
        process = self.start("router", ["-m", "fleet.cli.main", "router", *options])
        if wait:
            self.wait_router()
        return process

    def wait_router(self) -> None:
        """Return once the router's port accepts connections; AssertionError with its log if
        it exited first."""
        process = self.processes["router"]
        wait_until(lambda: self._port_open() or process.poll() is not None, 15.0)
        assert process.poll() is None, self.log("router")

    def start_sim(self, *arms: str, name: str = "sim") -> Process:
        """``fleet sim`` for the given arms (all simulated arms if none)."""
        argv = ["-m", "fleet.cli.main", "sim"]
        for arm in arms:
            argv += ["--arm", arm]
        return self.start(name, argv)

    def start_agent(self, *arms: str, name: str = "agent") -> Process:
        """``edge-agent --arm ...``."""
        argv = ["-m", "edge_agent"]
        for arm in arms or tuple(self.inventory.arms):
            argv += ["--arm", arm]
        return self.start(name, argv)

    def start_coordinator(self) -> Process:
        """``fleet coordinator``."""
        return self.start("coordinator", ["-m", "fleet.cli.main", "coordinator"])

    def start_fleet(self) -> FleetClient:
        """Router, all simulated arms, one agent for all arms; returns a connected client once
        every arm's link is ok. The three start side by side: the agent's Zenoh session keeps
        trying a router not yet listening (``RECONNECT_RETRY``). Measured over the e2e tests:
        0.67 s per fleet against 0.75 with the router waited for first (little: the starts
        share the two cores)."""
        self.start_router(wait=False)
        self.start_sim()
        self.start_agent()
        self.wait_router()
        client = self.client()
        try:
            wait_until(lambda: self.all_links_ok(client), 30.0)
        except AssertionError:
            raise AssertionError(f"the fleet did not come up:\n{self.diagnose(client)}") from None
        return client

    def diagnose(self, client: FleetClient) -> str:
        """What each process said and what the key space shows, for a failure message."""
        lines = [f"domain {self.domain}, endpoint {self.endpoint}"]
        lines.append(f"snapshot: {client.snapshot(wait_s=1.0)}")
        lines.append(f"agents alive: {client.agents_alive()}")
        for name, process in self.processes.items():
            lines.append(f"--- {name} (exit code {process.poll()}):\n{self.log(name)[-3000:]}")
        return "\n".join(lines)

    def client(self, principal: str = "operator") -> FleetClient:
        """A FleetClient on this fleet acting as ``principal`` (closed at teardown)."""
        client = FleetClient(self.inventory.with_principal(principal))
        self._clients.append(client)
        return client

    def all_links_ok(self, client: FleetClient) -> bool:
        """True when every arm reports status with link ok."""
        snapshot = client.snapshot(wait_s=1.5)
        return all(s is not None and s.link == "ok" for s, _j in snapshot.values())

    def stop(self, name: str, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int:
        """Signal the process by PID and wait; SIGKILL if it does not exit. Returns its code."""
        process = self.processes[name]
        if process.poll() is None:
            process.send_signal(sig)
        return self._reap(process, timeout_s)

    def _reap(self, process: Process, timeout_s: float) -> int:
        """Wait for a signalled process; SIGKILL if it does not exit (kept in ``killed`` and
        warned about: every process must stop on SIGTERM). Returns its code."""
        if process.poll() is None:
            try:
                process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=timeout_s)
                self.killed.append(
                    next((n for n, p in self.processes.items() if p is process), "?")
                )
        return int(process.returncode)

    def log(self, name: str) -> str:
        """The output of process ``name`` so far."""
        path = self._logs.get(name)
        return path.read_text(errors="replace") if path and path.exists() else ""

    def _port_open(self) -> bool:
        with socket.socket() as probe:
            return probe.connect_ex(("127.0.0.1", self.port)) == 0

    def close(self) -> None:
        """Close clients, then stop every process, newest first."""
        for client in self._clients:
            client.close()
        # Every process signalled first, then each waited for: they shut down side by side
        # (one after another cost 0.6-1.1 s per test).
        try:
            running = [p for p in reversed(list(self.processes.values())) if p.poll() is None]
            for process in running:
                process.send_signal(signal.SIGTERM)
                process.send_signal(signal.SIGCONT)  # one a test left frozen acts on it too
            for process in running:
                self._reap(process, 10.0)
        finally:  # the run's other tests need the domain and port back whatever happened
            self._domain_lock.close()
            release_port(self.port)
        hung = [name for name in self.processes if HUNG_AT_SHUTDOWN.search(self.log(name))]
        if self.killed or hung:
            # After every process is reaped: the suite's filterwarnings turn this into an error.
            logs = "\n".join(f"{name}: ...{self.log(name)[-600:]}" for name in self.killed)
            logs += "\n".join(f"{name}: ...{self.log(name)[-4000:]}" for name in hung)
            warnings.warn(
                f"killed, no exit within 10 s of SIGTERM: {', '.join(self.killed) or 'none'}; "
                f"stuck at shutdown, stacks printed: {', '.join(hung) or 'none'}\n{logs}",
                stacklevel=2,
            )

    def __enter__(self) -> FleetHarness:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
