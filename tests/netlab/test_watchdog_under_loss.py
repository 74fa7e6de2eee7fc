"""Issue 24: the watchdog under loss. Every kind's units move under the coordinator for
``D1_NETLAB_WATCHDOG_S`` seconds (default 40; 600 for the issue's 10 minutes) at 10 % loss +
20 ms per link: the arms by synchronized moves back and forth, the Dex1-1 by strokes to its
other end and the G1 by walking, each re-commanded at every move so every unit stays watched.
No agent may trip a unit's watchdog (``watchdog_s`` 0.5 s) while the coordinator is alive.
Before the two paths a beat held up by a TCP retransmission (>= 200 ms, doubling) or by a
blocking put could leave an agent without a beat for 0.5 s.

The devices are commanded as row 2 commands them (the coordinator sends arms only): from the
principal ``coordinator``, owned by the coordinator's id, so their agents watch the real
coordinator's heartbeat. Stand-in, not product: the lab's client sends them.

One run for every kind (``SharedRuns``: the first kind's test makes it); each kind's test
checks its own units. The figure: watchdog stops per unit (from the agents' logs), commands
served, and the refusals (the coordinator's commands are queries over TCP: not what this row
is about).
"""

from __future__ import annotations

import os
import re
import time
from collections import Counter
from typing import Any

import pytest

from testkit.load import OVERLOADED, overload
from tests.netlab.checks import restore
from tests.netlab.fleetlab import LabFleet, RemoteClient
from tests.netlab.labkinds import LAB_KIND_IDS, LAB_KINDS, LabKind, SharedRuns
from tests.netlab.rowreport import RowReport

ROW = "1"
LOSS = 0.10
DELAY_MS = 20.0
DURATION_S = float(os.environ.get("D1_NETLAB_WATCHDOG_S", "40"))
WATCHDOG_LINE = re.compile(r"stopped (.+?) by watchdog")
"""The agent's log line of a watchdog stop (``edge_agent/stops.py``): the units it latched."""

_RUN = SharedRuns()


def _watchdog_stops(lab1: LabFleet) -> Counter[str]:
    """Watchdog stops so far per unit, from every agent's log."""
    stops: Counter[str] = Counter()
    for name in lab1.lab.harness.processes:
        if name.startswith("agent-"):
            for line in WATCHDOG_LINE.findall(lab1.lab.log(name)):
                stops.update(unit.strip() for unit in line.split(","))
    return stops


def _command_devices(lab1: LabFleet, client: RemoteClient, owner: str) -> dict[str, bool]:
    """Each device its long move again, from the coordinator; unit -> accepted."""
    accepted = {}
    for kind in LAB_KINDS:
        if kind.is_arm:
            continue
        for unit in kind.units(lab1):
            state = client.call("device_state", unit=unit)["state"]
            command = kind.long_move(state) | {"owner": owner}
            sent = client.call(
                "device_command", unit=unit, command=command, principal="coordinator"
            )
            accepted[unit] = bool(sent["reply"]["ok"])
    return accepted


def _run(lab1: LabFleet) -> dict[str, Any]:
    """The row's one run, every kind moving: watchdog stops and commands per unit."""
    client = lab1.clients["client"]
    restore(lab1, client)
    owner = client.call("coordinator")["id"]
    assert owner is not None, "no fleet state from the coordinator"
    before = _watchdog_stops(lab1)
    sent: Counter[str] = Counter()
    served: Counter[str] = Counter()
    refusals: Counter[str] = Counter()
    try:
        lab1.lab.impair_all(loss=LOSS, delay_ms=DELAY_MS)
        deadline = time.monotonic() + DURATION_S
        seen = before
        while time.monotonic() < deadline:
            angle = 30.0 if sent["arm"] % 2 == 0 else -30.0
            move = {"op": "move_joints", "angles_deg": [angle, 0, 0, 0, 0, 0, 0], "mode": 1}
            moved = client.call("multi", _timeout=30.0, target="all", command=move, sync=True)
            sent["arm"] += 1
            served["arm"] += bool(moved["reply"]["ok"])
            error = moved["reply"].get("error")
            if error:
                refusals[f"{error.get('code')} {str(error.get('message'))[:80]}"] += 1
            for unit, ok in _command_devices(lab1, client, owner).items():
                sent[unit] += 1
                served[unit] += ok
            now = _watchdog_stops(lab1)
            if now != seen:  # counted; reset so that every unit moves (and is watched) again
                seen = now
                client.call("reset_wait", _timeout=40.0, timeout_s=30.0)
    finally:
        lab1.lab.clear()
        # Every unit still, and its lease (the coordinator's) ended: the next row's commands
        # are the lab client's own (the next test's restore resets the latch).
        client.call("estop", _timeout=60.0, timeout_s=30.0, reason="netlab row 1 watchdog end")
    after = _watchdog_stops(lab1)
    tripped = {u: after[u] - before[u] for u in after if after[u] > before[u]}
    return {"tripped": tripped, "sent": sent, "served": served, "refusals": refusals}


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
def test_no_false_watchdog_stop_at_10_pct_loss(
    lab1: LabFleet, kind: LabKind, row_report: RowReport
) -> None:
    run = _RUN.get("run", lambda: _run(lab1))
    units = kind.units(lab1)
    tripped = {u: n for u, n in run["tripped"].items() if u in units}
    counted = ["arm"] if kind.is_arm else units
    commands = ", ".join(f"{run['served'][c]}/{run['sent'][c]}" for c in counted)
    what = "synchronized moves" if kind.is_arm else "commands"
    refused = f"; refused: {run['refusals'].most_common(3)}" if kind.is_arm else ""
    row_report(
        f"{LOSS:.0%} + {DELAY_MS:g} ms per link for {DURATION_S:g} s, every kind moving: "
        f"{sum(tripped.values())} watchdog stops{f' {tripped}' if tripped else ''}; "
        f"{commands} {what} served{refused}",
        "no watchdog stop while the coordinator lives (at a load average over "
        f"{OVERLOADED:g} per core: XFAIL naming it)",
        {
            "tripped": tripped,
            "sent": {c: run["sent"][c] for c in counted},
            "served": {c: run["served"][c] for c in counted},
            "duration_s": DURATION_S,
        },
    )
    assert all(run["sent"][c] for c in counted), f"no {kind.name} command sent: {run['sent']}"
    load = overload()
    if tripped and load is not None:
        pytest.xfail(f"watchdog stops {tripped} with load average {load:.1f}")
    assert not tripped, f"false watchdog stops under {LOSS:.0%} loss: {tripped}"
