"""Issue 24: the watchdog under loss. Arms moving under the coordinator (synchronized moves
back and forth, so every arm stays watched) for ``D1_NETLAB_WATCHDOG_S`` seconds (default 40;
600 for the issue's 10 minutes) at 10 % loss + 20 ms per link: no agent may trip its watchdog
(``watchdog_s`` 0.5 s) while the coordinator is alive. Before the two paths a beat held up by
a TCP retransmission (>= 200 ms, doubling) or by a blocking put could leave an agent without a
beat for 0.5 s.

The figure: watchdog stops per agent (from the agents' logs), moves served, and the share of
moves the coordinator could not complete under the loss (its commands are queries over TCP:
not what this row is about).
"""

from __future__ import annotations

import os
import time
from collections import Counter

import pytest

from testkit.load import OVERLOADED, overload
from tests.netlab.checks import restore
from tests.netlab.fleetlab import LabFleet
from tests.netlab.rowreport import RowReport

ROW = "1"
LOSS = 0.10
DELAY_MS = 20.0
DURATION_S = float(os.environ.get("D1_NETLAB_WATCHDOG_S", "40"))


def _watchdog_stops(lab1: LabFleet) -> dict[str, int]:
    return {arm: lab1.lab.log(f"agent-{arm}").count("by watchdog") for arm in lab1.arms}


def test_no_false_watchdog_stop_at_10_pct_loss(lab1: LabFleet, row_report: RowReport) -> None:
    client = lab1.clients["client"]
    restore(lab1, client)
    before = _watchdog_stops(lab1)
    moves = ok = 0
    refusals: Counter[str] = Counter()
    try:
        lab1.lab.impair_all(loss=LOSS, delay_ms=DELAY_MS)
        deadline = time.monotonic() + DURATION_S
        seen = dict(before)
        while time.monotonic() < deadline:
            angle = 30.0 if moves % 2 == 0 else -30.0
            move = {"op": "move_joints", "angles_deg": [angle, 0, 0, 0, 0, 0, 0], "mode": 1}
            moved = client.call("multi", _timeout=30.0, target="all", command=move, sync=True)
            moves += 1
            ok += bool(moved["reply"]["ok"])
            error = moved["reply"].get("error")
            if error:
                refusals[f"{error.get('code')} {str(error.get('message'))[:80]}"] += 1
            now = _watchdog_stops(lab1)
            if now != seen:  # counted; reset so that the arms move (and are watched) again
                seen = now
                client.call("reset_wait", _timeout=40.0, timeout_s=30.0)
    finally:
        lab1.lab.clear()
    tripped = {a: n - before[a] for a, n in _watchdog_stops(lab1).items() if n > before[a]}
    row_report(
        f"{LOSS:.0%} + {DELAY_MS:g} ms per link for {DURATION_S:g} s: "
        f"{sum(tripped.values())} watchdog stops{f' {tripped}' if tripped else ''}; "
        f"{ok}/{moves} synchronized moves served; refused: {refusals.most_common(3)}",
        "no watchdog stop while the coordinator lives (at a load average over "
        f"{OVERLOADED:g} per core: XFAIL naming it)",
        {"tripped": tripped, "moves": moves, "served": ok, "duration_s": DURATION_S},
    )
    load = overload()
    if tripped and load is not None:
        pytest.xfail(f"watchdog stops {tripped} with load average {load:.1f}")
    assert not tripped, f"false watchdog stops under {LOSS:.0%} loss: {tripped}"
