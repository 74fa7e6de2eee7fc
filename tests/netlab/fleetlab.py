"""The fleet on the lab: routers, robot hosts (simulators + one edge agent), coordinator, client.

Two topologies:
1. ``one_router``: every process connects to one router;
2. ``site_routers``: a site router per group of arms, each joined to a central router; the
   agents connect to their site router, the coordinator and the clients to the central one.

Each process gets an inventory written for its host: the Zenoh endpoints it connects to, and
(for the robot hosts) DDS bound to the host's own interface with the host itself as the only
unicast peer, the NIC-binding path of a real arm network (a robot and its agent share a host
here, so DDS never crosses a cable; Zenoh always does).

A robot host is an arm host (its D1 arm, and the Dex1-1 mounted on it if the lab has one) or a
host of its own for a G1 (``LAB_DEVICES``). Each runs one ``fleet sim`` for what is on its card
and one ``edge-agent --interface lab-<host>`` serving all of it, as in production (one agent
process per card).
"""

from __future__ import annotations

import json
import queue
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from testkit.harness import wait_until
from tests.netlab.lab import FLEET, Host, NetLab

ARM_OCTET = 11
DEVICE_OCTET = 31
"""Hosts of their own for devices (a G1) get 192.168.123.31 on."""


@dataclass(frozen=True)
class LabDevice:
    """A simulated device of the lab: its inventory section, the host whose card it is on (a
    gripper: the host of the arm it is mounted on; a G1: a host of its own, named like it),
    and its kind's own inventory lines."""

    section: str
    host: str
    fields: str = ""


LAB_DEVICES = {
    # 100 Hz (the Dex1-1 sends 200-500 Hz): the lab's two cores are shared by some twenty
    # processes, and the agent's 20 ms speed window (the hold's confirmation) still spans two
    # samples. 2 rad/s: a full stroke takes 3.1 s, so a stop still finds the fingers moving
    # after row 1's second of loss before it (at the simulator's default 6 rad/s they arrived).
    "gl": LabDevice(
        "grippers",
        "a1",
        'family = "go"\nmount = "a1"\nsim_rate_hz = 100.0\nsim_speed_rad_s = 2.0\n',
    ),
    # The simulator's default settling (0.3 s of stepping after the velocity ends), spelled
    # out: the stop's confirmation waits for it, and the rows' bounds count it. rt/lowstate at
    # 10 Hz, not 100: each sample is ~1 ms of Python to build and ~0.5 ms for the agent to
    # take (the G1 cost ~20 % of a core at 100 Hz), no row reads it, and the agent only needs
    # one within its 0.5 s link_stale_s. The sportmodestate the stop rows confirm by stays
    # at 100 Hz.
    "h1": LabDevice(
        "g1", "h1", 'stop_action = "stop_move"\nsim_settle_s = 0.3\nsim_lowstate_hz = 10.0\n'
    ),
}
"""The devices of the lab's topologies: a Dex1-1 on arm a1, a G1 on host h1."""


def device_lines(devices: dict[str, tuple[LabDevice, Host]]) -> str:
    """The inventory tables of ``devices`` (id -> its definition and its host's card)."""
    return "".join(
        f'[{device.section}.{device_id}]\ninterface = "{host.interface}"\n'
        f'peers = ["{host.ip}"]\n{device.fields}\n'
        for device_id, (device, host) in devices.items()
    )


def inventory_text(
    domain: int,
    endpoints: list[str],
    arms: dict[str, Host],
    extra: str,
    devices: dict[str, tuple[LabDevice, Host]] | None = None,
) -> str:
    """An inventory of ``arms`` (arm id -> its host) and ``devices``, meeting on ``endpoints``."""
    lines = [
        f'[fleet]\nname = "{FLEET}"\n',
        f"[zenoh]\nendpoints = {json.dumps(endpoints)}\n",
        f"[dds]\ndomain_id = {domain}\npeers = []\n",
        "[defaults]\nsimulated = true\n",
    ]
    for i, (arm, host) in enumerate(arms.items()):
        lines.append(
            f'[arms.{arm}]\nsuffix = ""\ninterface = "{host.interface}"\n'
            f'peers = ["{host.ip}"]\nbase_xyz = [0.0, {0.6 * i:.1f}, 0.0]\n'
        )
    lines.append(device_lines(devices or {}))
    lines.append(extra)
    return "\n".join(lines)


class RemoteClient:
    """The test's side of ``clientd.py``: ``call(op, **params)`` returns the result."""

    def __init__(self, process: subprocess.Popen[bytes], log: Path) -> None:
        self.process = process
        self.log = log
        self._replies: queue.SimpleQueue[dict[str, Any]] = queue.SimpleQueue()
        self._next = 0
        self._lock = threading.Lock()
        threading.Thread(target=self._read, name="clientd-reader", daemon=True).start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            try:
                self._replies.put(json.loads(line))
            except json.JSONDecodeError:
                continue  # not a reply (clientd sends its own output to its log)
        self._replies.put({"id": None, "ok": False, "error": "clientd exited"})

    def call(self, op: str, _timeout: float = 60.0, **params: Any) -> Any:
        """One request; its result (RuntimeError if it failed or took longer than
        ``_timeout`` seconds)."""
        stdin = self.process.stdin
        assert stdin is not None
        with self._lock:
            self._next += 1
            rid = self._next
            stdin.write(json.dumps({"id": rid, "op": op, **params}).encode() + b"\n")
            stdin.flush()
            while True:
                try:
                    reply = self._replies.get(timeout=_timeout)
                except queue.Empty:
                    raise RuntimeError(f"clientd: no reply to {op} within {_timeout} s") from None
                if reply["id"] in (rid, None):
                    break
        if not reply["ok"]:
            tail = self.log.read_text(errors="replace")[-2000:] if self.log.exists() else ""
            raise RuntimeError(f"clientd {op}({params}): {reply['error']}\n{tail}")
        return reply["result"]


@dataclass
class LabFleet:
    """A fleet running on a NetLab."""

    lab: NetLab
    arms: dict[str, Host]
    routers: dict[str, tuple[str, list[str], list[str]]] = field(default_factory=dict)
    """router name -> (host, listen, connect)"""
    extra: str = ""
    clients: dict[str, RemoteClient] = field(default_factory=dict)
    devices: dict[str, LabDevice] = field(default_factory=dict)

    def device_hosts(self) -> dict[str, tuple[LabDevice, Host]]:
        """Every device with the host whose card it is on."""
        return {d: (dev, self.lab.hosts[dev.host]) for d, dev in self.devices.items()}

    def units_on(self, host: str) -> list[str]:
        """The arm and device ids on ``host``'s card."""
        arms = [host] if host in self.arms else []
        return arms + [d for d, dev in self.devices.items() if dev.host == host]

    def inventory(self, name: str, endpoints: list[str], host: str | None = None) -> Path:
        """Write the inventory of process ``name`` (with ``host``: only the robots on that
        host's card, for its simulator)."""
        path = self.lab.tmp_path / f"{name}.toml"
        arms, devices = self.arms, self.device_hosts()
        if host is not None:
            arms = {a: h for a, h in arms.items() if a == host}
            devices = {d: dh for d, dh in devices.items() if dh[0].host == host}
        text = inventory_text(self.lab.domain, endpoints, arms, self.extra, devices)
        path.write_text(text, encoding="utf-8")
        return path

    # ------------------------------------------------------------------ processes

    def start_router(self, name: str) -> None:
        """(Re)start router ``name`` on its host; returns once it listens."""
        host, listen, connect = self.routers[name]
        argv = ["-m", "fleet.cli.main", "router"]
        for endpoint in listen:
            argv += ["--listen", endpoint]
        for endpoint in connect:
            argv += ["--connect", endpoint]
        self.lab.start(name, host, argv, self.inventory(name, listen))
        self.lab.wait_listening(name)

    def start_robot_host(self, host: str, endpoints: list[str]) -> None:
        """The simulators of what is on ``host``'s card (DDS only: an arm and the gripper
        mounted on it, or a G1) and the one edge agent of that card, ``--interface``."""
        sim = ["-m", "fleet.cli.main", "sim", "--no-zenoh"]
        self.lab.start(f"sim-{host}", host, sim, self.inventory(f"sim-{host}", endpoints, host))
        agent = ["-m", "edge_agent", "--interface", self.lab.hosts[host].interface]
        self.lab.start(f"agent-{host}", host, agent, self.inventory(f"agent-{host}", endpoints))

    def start_coordinator(self, endpoints: list[str], host: str = "coord") -> None:
        """``fleet coordinator`` on its host."""
        argv = ["-m", "fleet.cli.main", "coordinator"]
        self.lab.start("coordinator", host, argv, self.inventory("coordinator", endpoints))

    def start_client(self, name: str, host: str, endpoints: list[str]) -> RemoteClient:
        """A clientd on ``host``."""
        inventory = self.inventory(name, endpoints)
        process = self.lab.start_piped(name, host, ["-m", "tests.netlab.clientd", str(inventory)])
        client = RemoteClient(process, self.lab.tmp_path / f"{name}.log")
        self.clients[name] = client
        return client

    def start_dds_tool(
        self, name: str, host: str, *args: str, wait_ready: bool = True
    ) -> subprocess.Popen[bytes]:
        """``ddstool.py`` on robot host ``host`` (an arm's host is named like the arm; a G1's
        host of its own like the G1), on that host's DDS network; waits until it says it is
        ready (a spy: matched with the agent's writer; a rogue or a forger: with the agent's
        reader)."""
        card = self.lab.hosts[host]
        argv = ["-m", "tests.netlab.ddstool", *args, "--domain", str(self.lab.domain)]
        argv += ["--interface", card.interface, "--peer", card.ip]
        process = self.lab.harness.start(name, argv, prefix=self.lab.prefix(host), inventory=False)
        if wait_ready:
            wait_until(lambda: '"ready"' in self.lab.log(name) or process.poll() is not None, 20.0)
            assert process.poll() is None, self.lab.log(name)
        return process

    def diagnose(self) -> str:
        """Every process's exit code and log tail, for a failure message."""
        parts = [f"lab {self.lab.tag}, impairments {self.lab.impairments}"]
        for name, code in self.lab.alive().items():
            parts.append(f"--- {name} (exit code {code}):\n{self.lab.log(name)[-1500:]}")
        return "\n".join(parts)


def _own_hosts(devices: dict[str, LabDevice], arm_ids: list[str]) -> list[str]:
    """The device hosts that are no arm's host (a G1's)."""
    return sorted({d.host for d in devices.values()} - set(arm_ids))


def one_router(
    tmp_path: Path, arms: int, extra: str = "", devices: dict[str, LabDevice] | None = None
) -> LabFleet:
    """Topology 1: router, coordinator, a client, ``arms`` arm hosts, the ``devices`` (on their
    arm's host, or a host of their own); every process up."""
    devices = devices or {}
    hosts = {"router": 2, "coord": 3, "client": 4, "viewer": 5}
    arm_ids = [f"a{i}" for i in range(1, arms + 1)]
    hosts.update({arm: ARM_OCTET + i for i, arm in enumerate(arm_ids)})
    own = _own_hosts(devices, arm_ids)
    hosts.update({host: DEVICE_OCTET + i for i, host in enumerate(own)})
    lab = NetLab(tmp_path, hosts)
    try:
        fleet = LabFleet(lab, {arm: lab.hosts[arm] for arm in arm_ids}, extra=extra)
        fleet.devices = dict(devices)
        endpoint = lab.hosts["router"].endpoint
        fleet.routers["router"] = ("router", [endpoint], [])
        fleet.start_router("router")
        for host in [*arm_ids, *own]:
            fleet.start_robot_host(host, [endpoint])
        return _with_coordinator_and_client(fleet, endpoint)
    except BaseException:
        lab.close()
        raise


def site_routers(
    tmp_path: Path,
    sites: dict[str, list[str]],
    extra: str = "",
    devices: dict[str, LabDevice] | None = None,
) -> LabFleet:
    """Topology 2: a central router; per site a router joined to it and its arm hosts; the
    coordinator and a client on the central router. The ``devices``' hosts of their own (a
    G1's) join the first site."""
    devices = devices or {}
    hosts = {"central": 2, "coord": 3, "client": 4}
    for i, site in enumerate(sites):
        hosts[site] = 6 + i
    arm_ids = [arm for arms in sites.values() for arm in arms]
    hosts.update({arm: ARM_OCTET + i for i, arm in enumerate(arm_ids)})
    own = _own_hosts(devices, arm_ids)
    hosts.update({host: DEVICE_OCTET + i for i, host in enumerate(own)})
    lab = NetLab(tmp_path, hosts)
    try:
        fleet = LabFleet(lab, {arm: lab.hosts[arm] for arm in arm_ids}, extra=extra)
        fleet.devices = dict(devices)
        central = lab.hosts["central"].endpoint
        fleet.routers["central"] = ("central", [central], [])
        fleet.start_router("central")
        for i, (site, arms) in enumerate(sites.items()):
            endpoint = lab.hosts[site].endpoint
            fleet.routers[site] = (site, [endpoint], [central])
            fleet.start_router(site)
            for host in [*arms, *(own if i == 0 else [])]:
                fleet.start_robot_host(host, [endpoint])
        return _with_coordinator_and_client(fleet, central)
    except BaseException:
        lab.close()
        raise


def _with_coordinator_and_client(fleet: LabFleet, endpoint: str) -> LabFleet:
    """Start the coordinator and the client on the router at ``endpoint``; wait until ready."""
    fleet.start_coordinator([endpoint])
    client = fleet.start_client("client", "client", [endpoint])
    _wait_ready(fleet, client)
    return fleet


def _wait_ready(fleet: LabFleet, client: RemoteClient) -> None:
    result = client.call("ready", _timeout=70.0, timeout_s=60.0)
    if not result["ready"]:
        raise AssertionError(f"the lab fleet did not come up: {result}\n{fleet.diagnose()}")
    wait_until(lambda: all(code is None for code in fleet.lab.alive().values()), 1.0)
