"""The fleet on the lab: routers, arm hosts (simulated arm + edge agent), coordinator, client.

Two topologies:
1. ``one_router``: every process connects to one router;
2. ``site_routers``: a site router per group of arms, each joined to a central router; the
   agents connect to their site router, the coordinator and the clients to the central one.

Each process gets an inventory written for its host: the Zenoh endpoints it connects to, and
(for the arm hosts) DDS bound to the host's own interface with the host itself as the only
unicast peer, the NIC-binding path of a real arm network (the arm and its agent share a host
here, so DDS never crosses a cable; Zenoh always does).
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


def inventory_text(domain: int, endpoints: list[str], arms: dict[str, Host], extra: str) -> str:
    """An inventory of ``arms`` (arm id -> its host), meeting on ``endpoints``."""
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

    def inventory(self, name: str, endpoints: list[str]) -> Path:
        """Write the inventory of process ``name``."""
        path = self.lab.tmp_path / f"{name}.toml"
        text = inventory_text(self.lab.domain, endpoints, self.arms, self.extra)
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

    def start_arm_host(self, arm: str, endpoints: list[str]) -> None:
        """The simulated arm (DDS only) and its edge agent on the arm's host."""
        sim = ["-m", "fleet.cli.main", "sim", "--arm", arm, "--no-zenoh"]
        self.lab.start(f"sim-{arm}", arm, sim, self.inventory(f"sim-{arm}", endpoints))
        agent = ["-m", "edge_agent", "--arm", arm]
        self.lab.start(f"agent-{arm}", arm, agent, self.inventory(f"agent-{arm}", endpoints))

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
        self, name: str, arm: str, *args: str, wait_ready: bool = True
    ) -> subprocess.Popen[bytes]:
        """``ddstool.py`` on ``arm``'s host, on that arm's DDS network; waits until it says it
        is ready (a spy: matched with the agent's writer; a rogue: with the agent's reader)."""
        host = self.arms[arm]
        argv = ["-m", "tests.netlab.ddstool", *args, "--domain", str(self.lab.domain)]
        argv += ["--interface", host.interface, "--peer", host.ip]
        process = self.lab.harness.start(name, argv, prefix=self.lab.prefix(arm), inventory=False)
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


def one_router(tmp_path: Path, arms: int, extra: str = "") -> LabFleet:
    """Topology 1: router, coordinator, a client, ``arms`` arm hosts; every process up."""
    hosts = {"router": 2, "coord": 3, "client": 4, "viewer": 5}
    arm_ids = [f"a{i}" for i in range(1, arms + 1)]
    hosts.update({arm: ARM_OCTET + i for i, arm in enumerate(arm_ids)})
    lab = NetLab(tmp_path, hosts)
    try:
        fleet = LabFleet(lab, {arm: lab.hosts[arm] for arm in arm_ids}, extra=extra)
        endpoint = lab.hosts["router"].endpoint
        fleet.routers["router"] = ("router", [endpoint], [])
        fleet.start_router("router")
        for arm in arm_ids:
            fleet.start_arm_host(arm, [endpoint])
        return _with_coordinator_and_client(fleet, endpoint)
    except BaseException:
        lab.close()
        raise


def site_routers(tmp_path: Path, sites: dict[str, list[str]], extra: str = "") -> LabFleet:
    """Topology 2: a central router; per site a router joined to it and its arm hosts; the
    coordinator and a client on the central router."""
    hosts = {"central": 2, "coord": 3, "client": 4}
    for i, site in enumerate(sites):
        hosts[site] = 6 + i
    arm_ids = [arm for arms in sites.values() for arm in arms]
    hosts.update({arm: ARM_OCTET + i for i, arm in enumerate(arm_ids)})
    lab = NetLab(tmp_path, hosts)
    try:
        fleet = LabFleet(lab, {arm: lab.hosts[arm] for arm in arm_ids}, extra=extra)
        central = lab.hosts["central"].endpoint
        fleet.routers["central"] = ("central", [central], [])
        fleet.start_router("central")
        for site, arms in sites.items():
            endpoint = lab.hosts[site].endpoint
            fleet.routers[site] = (site, [endpoint], [central])
            fleet.start_router(site)
            for arm in arms:
                fleet.start_arm_host(arm, [endpoint])
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
