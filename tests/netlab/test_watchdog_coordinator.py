"""Fault matrix, row 2: the coordinator dies (SIGKILL), freezes (SIGSTOP) or is cut off (its
link partitioned) during a synchronized move of every arm through it (a MultiArmRequest: the
arms are watched by the coordinator). Every arm must be held by its own agent's watchdog,
latched with the watchdog's reason, and stay still (also once the coordinator is back) until
an operator's reset.

Times are measured from the fault (the test's clock; the hosts share it) to the first status
that shows the watchdog stop, and to the arm seen still in its relayed joints (the first sample
from which every later one stays within 0.5 deg of the final pose; samples carry the agent's
receive stamp). Bound: watchdog_s (0.5 s) + one feedback period (0.1 s) + a 0.4 s margin for
what the measurement adds: the safety tick (0.05 s), the hold's settling (its target is the
pose of the last report, up to 0.1 s old, so a moving arm overshoots it and comes back: up to
~0.2 s in mode-0 smoothing) and the joints sample period (0.1 s). The status bound needs no
settling: watchdog_s + 0.1 + 0.1 s.
"""

from __future__ import annotations

import signal
import time
from typing import Any

import pytest

from tests.netlab.checks import STILL_DEG, joints_of, restore, statuses_of, still_since
from tests.netlab.fleetlab import LabFleet

WATCHDOG_S = 0.5
FEEDBACK_S = 0.1
MARGIN_S = 0.4
STATUS_BOUND_S = WATCHDOG_S + FEEDBACK_S + 0.1
STILL_BOUND_S = WATCHDOG_S + FEEDBACK_S + MARGIN_S
OBSERVE_S = 2.0
"""How long the arms are watched after the fault, and again after the coordinator is back."""


def _fault(lab1: LabFleet, how: str) -> None:
    process = lab1.lab.harness.processes["coordinator"]
    if how == "kill":
        process.send_signal(signal.SIGKILL)
    elif how == "freeze":
        process.send_signal(signal.SIGSTOP)
    else:
        lab1.lab.partition("coord")


def _undo(lab1: LabFleet, how: str) -> None:
    if how == "kill":
        lab1.lab.harness.processes["coordinator"].wait(timeout=10)
        lab1.start_coordinator([lab1.lab.hosts["router"].endpoint])
    elif how == "freeze":
        lab1.lab.harness.processes["coordinator"].send_signal(signal.SIGCONT)
    else:
        lab1.lab.heal("coord")


def _held(samples: list[Any], arm: str, fault_ns: int) -> dict[str, Any]:
    """When ``arm`` showed the watchdog stop and was still, relative to the fault."""
    stops = [
        s["stamp_ns"]
        for _t, s in statuses_of(samples, arm)
        if s["estopped"] and "watchdog" in (s["stop_reason"] or "") and s["stamp_ns"] >= fault_ns
    ]
    rows = [r for r in joints_of(samples, arm) if r[1] >= fault_ns]
    still = still_since(rows)
    assert still is not None, f"{arm}: no joints after the fault"
    moved = max(abs(a - b) for a, b in zip(rows[0][2], still[1]))
    return {
        "status_s": (min(stops) - fault_ns) / 1e9 if stops else None,
        "still_s": (still[0] - fault_ns) / 1e9,
        "moved_after_fault_deg": moved,
        "final": still[1],
    }


@pytest.mark.parametrize("how", ["kill", "freeze", "partition"])
def test_a_lost_coordinator_gets_every_watched_arm_held_until_a_reset(
    lab1: LabFleet, how: str
) -> None:
    client = lab1.clients["client"]
    restore(lab1, client)
    arms = list(lab1.arms)
    client.call("watch_start")
    snap = client.call("snapshot")["arms"]
    start = {arm: snap[arm][1]["angles_deg"][0] for arm in arms}
    target = -120.0 if sum(start.values()) > 0 else 120.0  # a long move: >= 1.3 s
    move = {"op": "move_joints", "angles_deg": [target, 0, 0, 0, 0, 0, 0], "mode": 1}
    client.call("watch_take")
    reply = client.call("multi", target="all", command=move, sync=True)["reply"]
    assert reply["ok"], reply
    fault_ns = time.time_ns()
    try:
        _fault(lab1, how)
        time.sleep(OBSERVE_S)
        during = client.call("watch_take")["samples"]
    finally:
        _undo(lab1, how)
    time.sleep(OBSERVE_S)
    after = client.call("watch_take")["samples"]
    held = {arm: _held(during, arm, fault_ns) for arm in arms}
    worst_status = max(h["status_s"] or float("inf") for h in held.values())
    worst_still = max(h["still_s"] for h in held.values())
    status_s = ", ".join(f"{h['status_s'] or float('inf'):.2f}" for h in held.values())
    moved = ", ".join(f"{h['moved_after_fault_deg']:.0f}" for h in held.values())
    print(
        f"\nrow 2, coordinator {how} mid-move: watchdog stop in the status after "
        f"{status_s} s "
        f"(max {worst_status:.2f}, bound {STATUS_BOUND_S:.2f}); still after max "
        f"{worst_still:.2f} s (bound {STILL_BOUND_S:.2f}); moved after the fault "
        f"{moved} deg"
    )
    for arm, h in held.items():
        assert h["status_s"] is not None, f"{arm}: no watchdog stop in its status: {h}"
        assert h["moved_after_fault_deg"] >= 2.0, f"{arm} was not moving at the fault: {h}"
    assert worst_status <= STATUS_BOUND_S
    assert worst_still <= STILL_BOUND_S
    # Nothing moves again, also with the coordinator back, until an operator resets.
    for arm in arms:
        rows = joints_of(after, arm)
        assert rows, f"{arm}: no joints after the coordinator came back"
        drift = max(
            abs(a - b) for _t, _s, angles in rows for a, b in zip(angles, held[arm]["final"])
        )
        assert drift <= STILL_DEG, f"{arm} moved {drift:.2f} deg after being held"
        latest = statuses_of(after, arm)[-1][1]
        assert latest["estopped"] and "watchdog" in latest["stop_reason"], latest
