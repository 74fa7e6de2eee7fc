"""What the lab tests measure and check, shared by the fault-matrix rows."""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

from fleet.d1 import protocol
from testkit.harness import wait_until
from tests.netlab.fleetlab import LabFleet, RemoteClient

STILL_DEG = 0.5
"""An arm whose reported angles stay within this of its final pose is still (the agent's own
standstill test is 3 reports within 0.3 deg)."""


DATAGRAM_LINK_S = 15.0
"""How long ``restore`` waits for every process's datagram session: after a router restart or
a spell of heavy loss a session over UDP learns its link died only after a lease without
keep-alives (3 s, ``fleet.wire.session.LEASE_S``), then reconnects. A row run with one missing
would measure the reliable path alone for that process, and say nothing about it."""


def restore(fleet: LabFleet, client: RemoteClient) -> None:
    """Put the lab back in order before a test: clean links, every process up (a dead
    coordinator restarted), every arm ready and unlatched, every process's datagram session
    linked to its router."""
    fleet.lab.clear()
    for name, code in fleet.lab.alive().items():
        if code is None:
            continue
        if name == "coordinator":
            endpoints = [fleet.lab.hosts[_router_of(fleet)].endpoint]
            fleet.start_coordinator(endpoints)
        elif not name.startswith(("stream", "rogue", "spy", "consumer", "load")):
            raise AssertionError(f"{name} died (exit code {code}):\n{fleet.lab.log(name)}")
    ready = client.call("ready", _timeout=70.0, timeout_s=60.0)
    assert ready["ready"], f"the lab fleet is not ready: {ready}\n{fleet.diagnose()}"
    cleared = client.call("reset_wait", _timeout=40.0, timeout_s=30.0)
    assert cleared["clear"], cleared
    processes = fleet.lab.harness.processes
    names = [n for n in processes if n.startswith("agent-")] + ["coordinator", "client"]
    linked: dict[str, bool] = {}

    def all_linked() -> bool:
        linked.update(datagram_linked(fleet, [n for n in names if n in processes]))
        return all(linked.values())

    try:
        wait_until(all_linked, DATAGRAM_LINK_S, interval_s=0.2)
    except AssertionError:
        raise AssertionError(f"no datagram link to the router: {linked}") from None


def _router_of(fleet: LabFleet) -> str:
    return "central" if "central" in fleet.routers else "router"


def percentile(values: list[float], q: float) -> float:
    """The q-th percentile (nearest rank) of ``values``."""
    ordered = sorted(values)
    rank = max(1, math.ceil(q / 100.0 * len(ordered)))
    return ordered[rank - 1]


def joints_of(samples: list[Any], arm: str) -> list[tuple[int, int, list[float]]]:
    """(arrival ns, stamp ns, angles) of ``arm``'s joints samples, in stamp order."""
    rows = [
        (t, value["stamp_ns"], value["angles_deg"])
        for t, a, channel, value in samples
        if a == arm and channel == "joints"
    ]
    return sorted(rows, key=lambda row: row[1])


def statuses_of(samples: list[Any], arm: str) -> list[tuple[int, dict[str, Any]]]:
    """(arrival ns, status) of ``arm``'s status samples, in arrival order."""
    return [(t, value) for t, a, channel, value in samples if a == arm and channel == "status"]


def still_since(
    rows: list[tuple[int, int, list[float]]], tolerance: float = STILL_DEG
) -> tuple[int, list[float]] | None:
    """The stamp from which every later sample stays within ``tolerance`` (an arm's
    STILL_DEG; a device's in its own pose's unit) of the last one (and that last pose); None
    without samples."""
    if not rows:
        return None
    final = rows[-1][2]
    since = rows[-1][1]
    for _t, stamp, angles in reversed(rows):
        if max(abs(a - b) for a, b in zip(angles, final)) > tolerance:
            break
        since = stamp
    return since, final


def spread_deg(rows: list[tuple[int, int, list[float]]]) -> float:
    """How far apart the samples are, at most, on any joint."""
    if not rows:
        return 0.0
    return max(max(r[2][j] for r in rows) - min(r[2][j] for r in rows) for j in range(7))


def commands_seen(spy_log: str, since_ns: int = 0) -> list[tuple[int, int, object]]:
    """(time, seq, typed command) of every D1 command a ddstool spy saw since ``since_ns``."""
    seen = []
    for line in spy_log.splitlines():
        if not line.startswith('{"t_ns"'):
            continue
        row = json.loads(line)
        if row["t_ns"] < since_ns:
            continue
        seq, command = protocol.decode_command(row["data"])
        seen.append((row["t_ns"], seq, command))
    return seen


def joint_moves(seen: list[tuple[int, int, object]], joint: int) -> Counter[float]:
    """How many times each ``move_joint`` angle of ``joint`` was written to the arm."""
    return Counter(
        round(c.angle_deg, 3)
        for _t, _seq, c in seen
        if isinstance(c, protocol.SetJointAngle) and c.joint == joint
    )


def datagram_linked(fleet: LabFleet, names: list[str], port: int = 7447) -> dict[str, bool]:
    """Process name -> whether it holds a connected UDP socket to a router's Zenoh ``port``
    (the stop's datagram path, issue 24): read from ``/proc/<pid>/net/udp`` as the process
    sees its namespace (state 01: a connected datagram socket)."""
    linked: dict[str, bool] = {}
    for name in names:
        pid = fleet.lab.harness.processes[name].pid
        try:
            rows = Path(f"/proc/{pid}/net/udp").read_text().splitlines()[1:]
        except OSError:
            linked[name] = False
            continue
        linked[name] = any(
            row.split()[2].endswith(f":{port:04X}") and row.split()[3] == "01" for row in rows
        )
    return linked
