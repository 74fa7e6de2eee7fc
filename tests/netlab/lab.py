"""A multi-host test bed in network namespaces: hosts on one switched arm network
(192.168.123.0/24, as on a real D1 network), each link with netem-style impairments.

Layout (names unique per run: ``d1nl-<pid>-<n>-<host>``):

- a *switch* namespace holding a Linux bridge (``br0``) and the cable process (``cable.py``);
  nothing is created in the root namespace, so the machine's own interfaces are never touched;
- one namespace per *host* (an arm host runs the simulated arm and its edge agent; a router,
  the coordinator, a client each get their own), with one interface ``lab-<host>`` at
  ``192.168.123.<n>`` whose other end is a port of the bridge, through the host's cable.

The test process stays in the root namespace; everything that talks to the lab runs as a
subprocess under ``ip netns exec`` (``NetLab.start``), tracked by PID by a FleetHarness.

API: ``lab.impair(host, loss=, delay_ms=, jitter_ms=, duplicate=, reorder=)`` (both directions
of the host's link), ``lab.impair_all(...)``, ``lab.partition(host)`` / ``lab.heal(host)``
(every frame of the link dropped, the impairment kept for after), ``lab.clear()``.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import shutil
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from testkit.harness import FleetHarness, wait_until
from tests.netlab.cable import Impairment

SUBNET = "192.168.123"
PREFIX = "d1nl"
FLEET = "netlab"
ZENOH_PORT = 7447
_labs = itertools.count(1)
REPO = Path(__file__).resolve().parents[2]


def why_no_lab() -> str | None:
    """Why this machine cannot build the lab (None: it can)."""
    if os.geteuid() != 0:
        return "the network lab needs root (ip netns, TAP devices)"
    if shutil.which("ip") is None:
        return "the network lab needs iproute2's `ip` (apt-get install iproute2)"
    if not os.path.exists("/dev/net/tun"):
        return "the network lab needs /dev/net/tun (TAP devices) for its cables"
    probe = f"{PREFIX}-probe-{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, timeout=10)
    if made.returncode != 0:
        return f"cannot create a network namespace: {made.stderr.decode().strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=10)
    return None


def netem_available() -> bool:
    """True when the kernel has sch_netem (this lab emulates it in userspace either way)."""
    probe = f"{PREFIX}-netem-{os.getpid()}"
    try:
        _ip("netns", "add", probe)
        _ip("-n", probe, "link", "add", "p0", "type", "veth", "peer", "name", "p1")
        done = subprocess.run(
            ["ip", "netns", "exec", probe, "tc", "qdisc", "add", "dev", "p0", "root", "netem"],
            capture_output=True,
            timeout=10,
        )
        return done.returncode == 0
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=10)


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, timeout=10)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.decode().strip()}")


def remove_stale_namespaces() -> list[str]:
    """Delete lab namespaces left by runs whose process is gone (a killed pytest)."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, timeout=10, text=True)
    removed = []
    for line in listed.stdout.splitlines():
        name = line.split()[0] if line.split() else ""
        found = re.match(rf"^{PREFIX}-(\d+)-\d+-", name)
        if found and not os.path.exists(f"/proc/{found.group(1)}"):
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=10)
            removed.append(name)
    return removed


@dataclass(frozen=True)
class Host:
    """One host of the lab."""

    name: str
    ns: str
    ip: str
    interface: str

    @property
    def endpoint(self) -> str:
        """The Zenoh endpoint a router on this host listens on."""
        return f"tcp/{self.ip}:{ZENOH_PORT}"


class Cable:
    """The cable process of one lab (JSON lines on its stdin and stdout)."""

    def __init__(self, process: subprocess.Popen[bytes]) -> None:
        self.process = process
        self._lock = threading.Lock()

    def call(self, **request: object) -> dict[str, object]:
        """One control request, its reply."""
        stdin, stdout = self.process.stdin, self.process.stdout
        assert stdin is not None and stdout is not None
        with self._lock:
            stdin.write(json.dumps(request).encode() + b"\n")
            stdin.flush()
            line = stdout.readline()
        if not line:
            raise RuntimeError(f"the cable process died (exit code {self.process.poll()})")
        reply: dict[str, object] = json.loads(line)
        if not reply.get("ok"):
            raise RuntimeError(f"cable: {request}: {reply.get('error')}")
        return reply


class NetLab:
    """Namespaces, cables and processes of one lab. A context manager; ``close()`` removes
    everything it made, also after a failure half way through ``__init__``."""

    def __init__(self, tmp_path: Path, hosts: dict[str, int]) -> None:
        """``hosts``: name -> last octet of its address (192.168.123.<n>)."""
        remove_stale_namespaces()
        self.tmp_path = tmp_path
        self.tag = f"{PREFIX}-{os.getpid()}-{next(_labs)}"
        # The harness tracks processes by PID and reserves a DDS domain; its own loopback
        # inventory (one arm) is not used: each lab process gets one written for its host.
        self.harness = FleetHarness(tmp_path, arms=1)
        self.domain = self.harness.domain
        self.switch_ns = f"{self.tag}-sw"
        self.hosts: dict[str, Host] = {}
        self.impairments: dict[str, Impairment] = {}
        self._namespaces: list[str] = []
        self.cable: Cable | None = None
        try:
            self._build(hosts)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ building

    def _namespace(self, name: str) -> None:
        _ip("netns", "add", name)
        self._namespaces.append(name)
        _ip("-n", name, "link", "set", "lo", "up")
        # No IPv6 on the lab: no router solicitations or MLD reports on the cables.
        for conf in ("all", "default"):
            _sysctl(name, f"net.ipv6.conf.{conf}.disable_ipv6=1")

    def _build(self, hosts: dict[str, int]) -> None:
        sw = self.switch_ns
        self._namespace(sw)
        _ip("-n", sw, "link", "add", "br0", "type", "bridge", "stp_state", "0")
        _ip("-n", sw, "link", "set", "br0", "up")
        self.cable = Cable(self.start_piped("cable", None, ["-m", "tests.netlab.cable", "7"]))
        for name, octet in hosts.items():
            host = Host(name, f"{self.tag}-{name}", f"{SUBNET}.{octet}", f"lab-{name}")
            self._namespace(host.ns)
            self.cable.call(op="add", link=name, host_if=host.interface, switch_if=f"p-{name}")
            _ip("-n", sw, "link", "set", f"p-{name}", "master", "br0", "up")
            _ip("-n", sw, "link", "set", host.interface, "netns", host.ns)
            _ip("-n", host.ns, "addr", "add", f"{host.ip}/24", "dev", host.interface)
            _ip("-n", host.ns, "link", "set", host.interface, "up")
            self.hosts[name] = host
            self.impairments[name] = Impairment()

    # ------------------------------------------------------------------ impairments

    def impair(
        self,
        host: str,
        loss: float = 0.0,
        delay_ms: float = 0.0,
        jitter_ms: float = 0.0,
        duplicate: float = 0.0,
        reorder: float = 0.0,
    ) -> None:
        """Impair ``host``'s link, both ways: netem's loss, delay, jitter, duplicate, reorder
        (probabilities 0..1). Replaces the link's previous impairment (a partition stays)."""
        down = self.impairments[host].down
        self._set(host, Impairment(loss, delay_ms, jitter_ms, duplicate, reorder, down))

    def impair_all(self, **impairment: float) -> None:
        """The same impairment on every link."""
        for host in self.hosts:
            self.impair(host, **impairment)

    def partition(self, host: str) -> None:
        """Cut ``host`` off: every frame on its link is dropped, both ways (its interface
        stays up, as when a switch port or a cable further on fails)."""
        current = self.impairments[host]
        self._set(host, Impairment(**{**current.__dict__, "down": True}))

    def heal(self, host: str) -> None:
        """Undo ``partition`` (the link's impairment, if any, applies again)."""
        current = self.impairments[host]
        self._set(host, Impairment(**{**current.__dict__, "down": False}))

    def clear(self) -> None:
        """Every link clean again."""
        for host in self.hosts:
            self._set(host, Impairment())

    def _set(self, host: str, impairment: Impairment) -> None:
        assert self.cable is not None
        self.cable.call(op="set", link=host, **impairment.__dict__)
        self.impairments[host] = impairment

    def link_stats(self) -> dict[str, dict[str, int]]:
        """Frame counters of every link (frames, dropped, duplicated, ...)."""
        assert self.cable is not None
        links = self.cable.call(op="stats")["links"]
        assert isinstance(links, dict)
        return links

    def sysctl(self, host: str, setting: str) -> None:
        """Set a per-namespace sysctl (``net.ipv4.tcp_rmem=4096 16384 65536``) on ``host``."""
        _sysctl(self.hosts[host].ns, setting)

    # ------------------------------------------------------------------ processes

    def prefix(self, host: str) -> tuple[str, ...]:
        """The command prefix that runs a program on ``host``."""
        return ("ip", "netns", "exec", self.hosts[host].ns)

    def start(
        self, name: str, host: str, argv: list[str], inventory: Path | None = None
    ) -> subprocess.Popen[bytes]:
        """``python argv [--inventory inventory]`` on ``host``, output to ``<name>.log``."""
        extra = ["--inventory", str(inventory)] if inventory is not None else []
        return self.harness.start(name, [*argv, *extra], prefix=self.prefix(host), inventory=False)

    def start_piped(self, name: str, host: str | None, argv: list[str]) -> subprocess.Popen[bytes]:
        """``python argv`` on ``host`` (None: in the switch namespace) with stdin and stdout as
        pipes, stderr to ``<name>.log``."""
        log_path = self.tmp_path / f"{name}.log"
        prefix = self.prefix(host) if host is not None else ("ip", "netns", "exec", self.switch_ns)
        with open(log_path, "wb") as log:
            process = subprocess.Popen(
                [*prefix, sys.executable, *argv],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
                cwd=REPO,
                env={**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(REPO)},
            )
        self.harness.processes[name] = process
        self.harness._logs[name] = log_path  # noqa: SLF001 - the harness's log table
        return process

    def wait_listening(self, name: str, port: int = ZENOH_PORT, timeout_s: float = 15.0) -> None:
        """Wait until process ``name`` listens on TCP ``port`` (read from the process's own
        namespace view of /proc/<pid>/net/tcp: nothing needs to connect from here)."""
        process = self.harness.processes[name]

        def listening() -> bool:
            if process.poll() is not None:
                raise AssertionError(f"{name} exited {process.returncode}:\n{self.log(name)}")
            try:
                table = Path(f"/proc/{process.pid}/net/tcp").read_text()
            except OSError:
                return False
            return any(
                f":{port:04X} " in row.split()[1] + " " and row.split()[3] == "0A"
                for row in table.splitlines()[1:]
            )

        wait_until(listening, timeout_s)

    def stop(self, name: str, sig: int = 15, timeout_s: float = 10.0) -> int:
        """Signal process ``name`` by PID and wait for it (SIGKILL after ``timeout_s``)."""
        return self.harness.stop(name, sig, timeout_s)

    def log(self, name: str) -> str:
        """What process ``name`` wrote."""
        return self.harness.log(name)

    def alive(self) -> dict[str, int | None]:
        """Exit code of every process started (None: running)."""
        return {n: p.poll() for n, p in self.harness.processes.items()}

    # ------------------------------------------------------------------ teardown

    def close(self) -> None:
        """Stop every process (newest first, the cable last), delete every namespace."""
        # The harness stops the newest first: the cable (started first) goes last, so no
        # process loses its link while it shuts down.
        try:
            self.harness.close()
        finally:
            for process in self.harness.processes.values():
                for pipe in (process.stdin, process.stdout):
                    if pipe is not None:
                        pipe.close()
            for ns in reversed(self._namespaces):
                subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10)
            self._namespaces.clear()

    def __enter__(self) -> NetLab:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _sysctl(ns: str, setting: str) -> None:
    key, value = setting.split("=")
    path = "/proc/sys/" + key.replace(".", "/")
    subprocess.run(
        ["ip", "netns", "exec", ns, "sh", "-c", f"echo '{value}' > {path}"],
        capture_output=True,
        timeout=10,
    )
