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

Once per kind (``LAB_KINDS``), one fault per kind (not shared as rows 1 and 3 share theirs: a
shared run, the devices moved under the coordinator and then the arms' synchronized move, took
10-19 s before its fault, by when every unit had arrived; not diagnosed). The coordinator commands
arms only (a MultiArmRequest has no device target), so a device is moved under it as the
coordinator's own command would reach the device's agent: from the principal ``coordinator``,
its owner the coordinator's id (read from its fleet state); the agent then watches that
coordinator's heartbeat, the real process's, and the same three faults silence it. Stand-in,
not product: the command is sent by the lab's client. The bounds: a device's state carries its
latch at its next put (``DeviceStops``: not at once, as an arm's status), a gripper's every 20
ms, a G1's at its ``relay_hz`` of 10 Hz or on an FSM change, so the G1's status bound is
watchdog_s + the safety tick (0.05) + 0.1 + the same 0.1 margin (0.75 s; measured 0.72 s once
at load 8.6 against the arm's 0.7); the gripper keeps the arm's. Still, a gripper: its hold on
the same tick and one simulator step (10 ms at the lab's 100 Hz); a G1: its stop_move, then
the simulator's ``sim_settle_s`` (0.3 s) of stepping and a 10 ms state: 0.5 + 0.05 + 0.3 +
0.01, 0.86 s of the arm's 1.0 s bound, which it keeps.
"""

from __future__ import annotations

import signal
import time
from typing import Any

import pytest

from edge_agent.stops import SAFETY_TICK_S
from testkit.load import xfail_if_overloaded
from tests.netlab.checks import restore, still_since
from tests.netlab.fleetlab import LabFleet, RemoteClient
from tests.netlab.labkinds import LAB_KIND_IDS, LAB_KINDS, LabKind, move_devices
from tests.netlab.rowreport import RowReport

ROW = "2"
WATCHDOG_S = 0.5
FEEDBACK_S = 0.1
MARGIN_S = 0.4
G1_STATE_S = 0.1
"""The G1's state period (``relay_hz`` 10 Hz): its latch rides the next one."""
STATUS_BOUNDS_S = {
    "arm": WATCHDOG_S + FEEDBACK_S + 0.1,
    "gripper": WATCHDOG_S + FEEDBACK_S + 0.1,
    "g1": WATCHDOG_S + SAFETY_TICK_S + G1_STATE_S + 0.1,
}
STILL_BOUND_S = WATCHDOG_S + FEEDBACK_S + MARGIN_S
OBSERVE_S = 2.0
"""How long the arms are watched after the fault, and again after the coordinator is back."""
ATTEMPTS = 2
"""Runs of the fault before a unit's missing watchdog stop fails the row: a run whose units had
all arrived before the fault measured nothing (seen once in CI: every arm at its target with
no stop; the reply's and the writes' times are now kept to tell why)."""


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


def _move_under_coordinator(lab1: LabFleet, client: RemoteClient, kind: LabKind) -> dict[str, Any]:
    """Set the kind's units moving under the coordinator (see the module docstring); the
    client's recording starts just before. For arms: the target, how long the synchronized
    move's reply took and when each arm's command was written (what a run in which an arm had
    already arrived at the fault is explained by)."""
    if kind.is_arm:
        snap = client.call("snapshot")["arms"]
        start = [snap[arm][1]["angles_deg"][0] for arm in lab1.arms]
        # A long move (>= 1.3 s) for every arm: an arm already at the target is not moving
        # under the coordinator when it fails, so nothing watches it (an earlier row can leave
        # one arm at -120 and the others elsewhere); if no end is far from every arm, from 0.
        target = max((-120.0, 120.0), key=lambda t: min(abs(t - a) for a in start))
        if min(abs(target - a) for a in start) < 90.0:
            home = {"op": "move_joints", "angles_deg": [0.0] * 7, "mode": 1, "wait_reached": True}
            reply = client.call("multi", target="all", command=home, sync=True)["reply"]
            assert reply["ok"], reply
            target = 120.0
        move = {"op": "move_joints", "angles_deg": [target, 0, 0, 0, 0, 0, 0], "mode": 1}
        client.call("watch_take")
        multi = client.call("multi", target="all", command=move, sync=True)
        reply = multi["reply"]
        assert reply["ok"], reply
        written = {arm: r["written_ns"] for arm, r in reply["replies"].items()}
        return {"target_deg": target, "reply_s": round(multi["elapsed_s"], 3), "written": written}
    coordinator = client.call("coordinator")["id"]
    assert coordinator is not None, "no fleet state from the coordinator"
    client.call("watch_take")
    timings: dict[str, dict[str, float]] = {}
    moved = move_devices(lab1, client, kind, "coordinator", coordinator, timings)
    assert moved, f"a {kind.name} refused the coordinator's command"
    return {"commands": timings}


def _fault_during_a_move(
    lab1: LabFleet, client: RemoteClient, kind: LabKind, how: str
) -> tuple[dict[str, dict[str, Any]], list[Any], dict[str, Any]]:
    """One run: the kind's units set moving under the coordinator, the fault, ``OBSERVE_S``
    watched, the coordinator back, ``OBSERVE_S`` more. How each unit was held, the samples
    after, and the move (see ``_move_under_coordinator``, with the fault's time)."""
    restore(lab1, client)
    client.call("watch_start")
    move = _move_under_coordinator(lab1, client, kind)
    fault_ns = time.time_ns()
    try:
        _fault(lab1, how)
        time.sleep(OBSERVE_S)
        during = client.call("watch_take")["samples"]
    finally:
        _undo(lab1, how)
    time.sleep(OBSERVE_S)
    after = client.call("watch_take")["samples"]
    held = {unit: _held(kind, during, unit, fault_ns) for unit in kind.units(lab1)}
    for timing in move.get("commands", {}).values():
        # A G1 walks 3 s: a command whose reply (or motion) came late can end before a fault.
        timing["moving_before_fault_s"] = round((fault_ns - timing.pop("moving_ns")) / 1e9, 3)
    if "written" in move:
        move["written_before_fault_s"] = {
            arm: None if ns is None else round((fault_ns - ns) / 1e9, 3)
            for arm, ns in move.pop("written").items()
        }
    return held, after, move


def _held(kind: LabKind, samples: list[Any], unit: str, fault_ns: int) -> dict[str, Any]:
    """When ``unit`` showed the watchdog stop and was still, relative to the fault."""
    stops = [
        s["stamp_ns"]
        for _t, s in kind.latches(samples, unit)
        if s["estopped"] and "watchdog" in (s["stop_reason"] or "") and s["stamp_ns"] >= fault_ns
    ]
    rows = [r for r in kind.poses(samples, unit) if r[1] >= fault_ns]
    still = still_since(rows, kind.still_tol)
    assert still is not None, f"{unit}: no pose after the fault"
    moved = max(abs(a - b) for a, b in zip(rows[0][2], still[1]))
    return {
        "status_s": (min(stops) - fault_ns) / 1e9 if stops else None,
        "still_s": (still[0] - fault_ns) / 1e9,
        "moved_after_fault_deg": moved,
        "final": still[1],
    }


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
@pytest.mark.parametrize("how", ["kill", "freeze", "partition"])
def test_a_lost_coordinator_gets_every_watched_unit_held_until_a_reset(
    lab1: LabFleet, how: str, kind: LabKind, row_report: RowReport
) -> None:
    client = lab1.clients["client"]
    units = kind.units(lab1)
    missed: list[dict[str, Any]] = []
    for _attempt in range(ATTEMPTS):
        held, after, move = _fault_during_a_move(lab1, client, kind, how)
        idle = [u for u, h in held.items() if h["moved_after_fault_deg"] < kind.moved_min]
        if not idle:
            break
        # The move had ended before the fault (its reply came after the arms arrived): the
        # run measured nothing (nothing watched them). Kept, shown, and run once more.
        missed.append({"idle_at_fault": idle, "held": held, "move": move})
        print(f"\nthe move had ended before the fault for {idle}: {move}; again")
    worst_status = max(h["status_s"] or float("inf") for h in held.values())
    worst_still = max(h["still_s"] for h in held.values())
    status_s = ", ".join(f"{h['status_s'] or float('inf'):.2f}" for h in held.values())
    digits = 0 if kind.is_arm else 2
    moved = ", ".join(f"{h['moved_after_fault_deg']:.{digits}f}" for h in held.values())
    status_bound = STATUS_BOUNDS_S[kind.name]
    row_report(
        f"watchdog stop in the {'status' if kind.is_arm else 'state'} after {status_s} s "
        f"(max {worst_status:.2f}); still "
        f"after max {worst_still:.2f} s; moved after the fault {moved} {UNITS[kind.name]}",
        f"watchdog stop in the {'status' if kind.is_arm else 'state'} <= {status_bound:.2f} "
        f"s; still <= {STILL_BOUND_S:.2f} s; no motion for {OBSERVE_S:g} s after, also with "
        "the coordinator back, until a reset",
        {"held": held, "move": move, "missed_runs": missed},
    )
    for unit, h in held.items():
        assert h["status_s"] is not None, (
            f"{unit}: no watchdog stop in its status: {h}; the move: {move}; earlier runs: {missed}"
        )
        moving = h["moved_after_fault_deg"] >= kind.moved_min
        assert moving, f"{unit} was not moving at the fault: {h}; the move: {move}; {missed}"
    slow = [f"watchdog stop > {status_bound:.2f} s"] if worst_status > status_bound else []
    slow += [f"still > {STILL_BOUND_S:.2f} s"] if worst_still > STILL_BOUND_S else []
    # Nothing moves again, also with the coordinator back, until an operator resets.
    for unit in units:
        rows = kind.poses(after, unit)
        assert rows, f"{unit}: no pose after the coordinator came back"
        drift = max(abs(a - b) for _t, _s, pose in rows for a, b in zip(pose, held[unit]["final"]))
        assert drift <= kind.still_tol, f"{unit} moved {drift:.2f} after being held"
        latest = kind.latches(after, unit)[-1][1]
        assert latest["estopped"] and "watchdog" in latest["stop_reason"], latest
    # The times last: a miss on an overloaded host (at load 7.1 the G1's state said so after
    # 0.77 s) still had every check above.
    xfail_if_overloaded(slow)
    assert not slow, slow


UNITS = {"arm": "deg", "gripper": "rad", "g1": "(fsm_mode)"}
"""What a kind's pose change is counted in."""
