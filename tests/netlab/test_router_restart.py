"""Fault matrix, row 3: routers killed (SIGKILL) and restarted.

Topology 2 (a site router per pair of arms joined to a central router; agents on their site
router, the coordinator and the client on the central one): the site router of a1/a2, then the
central router. Topology 1: its one router. Each time:
- every agent and client reconnects by itself (Zenoh clients retry their endpoints; a site
  router retries the central one) and joints of every arm reach the client again; the figure
  is the time from the restarted router's start to the first joints sample of each arm
  stamped after it; bounded (REJOIN_BOUND_S) from the moment the router listens again, so that
  a loaded host's slow router start-up is not counted as the fleet's reconnect;
- a stop latched before the outage is still latched after it (the agent holds the latch; the
  coordinator repeats it in its heartbeat);
- no command is executed twice: a client streams ``move_joint`` commands with distinct angles
  through the outage, and a DDS spy on the arm's own command topic (in the arm's namespace)
  counts what the arm received: every angle at most once, every acknowledged one exactly once.

Once per kind (``LAB_KINDS``) for the latched unit: an arm, the Dex1-1 on a1, the G1 (its host
on site1 in topology 2): latched through its own agent before the outage, still latched (its
state's latch and reason) and still (``LabKind.poses``) after it; its state, stamped after the
restart, counts in the rejoin figure. The streamed commands go to an arm in every run.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from typing import Any

import pytest

from testkit.harness import wait_until
from tests.netlab.checks import commands_seen, joint_moves, restore
from tests.netlab.fleetlab import LAB_DEVICES, LabFleet, site_routers
from tests.netlab.labkinds import LAB_KIND_IDS, LAB_KINDS, LabKind

SITES = {"site1": ["a1", "a2"], "site2": ["a3", "a4"]}
OUTAGE_S = 1.0
REJOIN_BOUND_S = 5.0
"""From the restarted router listening: the Zenoh clients' and the site routers' next reconnect
attempt (every 1 s at most: ``fleet.wire.session.RECONNECT_RETRY``), then the next joints
sample. The router's own start-up (0.2-0.4 s here, 1-2 s on a loaded host) is reported, not
bounded: with Zenoh's default back-off (up to 4 s) a start-up of 2 s gave 6.05 s."""


@pytest.fixture(scope="module")
def lab2(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LabFleet]:
    """Topology 2 (the Dex1-1 on a1, the G1 on site1) with a DDS spy on the command topic of
    a1 and of a3."""
    fleet = site_routers(tmp_path_factory.mktemp("netlab2"), SITES, devices=LAB_DEVICES)
    try:
        for arm in ("a1", "a3"):
            fleet.start_dds_tool(f"spy-{arm}", arm, "spy")
        yield fleet
    finally:
        fleet.lab.close()


def _restart_router(
    fleet: LabFleet,
    router: str,
    latched: tuple[LabKind, str],
    streamed_arm: str,
    watched: list[str],
) -> dict[str, Any]:
    """Kill ``router`` while ``streamed_arm`` is commanded and the ``latched`` unit (of its
    kind) is stopped; restart it; measure and check. Returns the figures."""
    kind, unit = latched
    watched = [*watched, *([] if kind.is_arm else [unit])]
    client = fleet.clients["client"]
    restore(fleet, client)
    acks = client.call("estop", arm=unit, timeout_s=5.0, reason="latched before")["acks"]
    ack = acks[kind.label(unit)]
    assert ack and ack["still_ns"], acks
    client.call("watch_start")
    client.call("watch_take")
    spy = f"spy-{streamed_arm}"
    if spy not in fleet.lab.harness.processes:
        fleet.start_dds_tool(spy, streamed_arm, "spy")
    since_ns = time.time_ns()
    base = round(time.time() % 50, 1)  # angles of this run differ from every earlier run's
    angles = [base + 0.25 * i for i in range(200)]
    client.call("stream_start", name="s", arm=streamed_arm, joint=0, angles=angles, period_s=0.2)
    time.sleep(0.8)
    fleet.lab.stop(router, signal.SIGKILL)
    time.sleep(OUTAGE_S)
    restart_ns = time.time_ns()
    fleet.start_router(router)
    listening_s = (time.time_ns() - restart_ns) / 1e9
    first: dict[str, int] = {}
    samples: list[Any] = []

    def rejoined() -> bool:
        for t, arm, channel, value in client.call("watch_take")["samples"]:
            samples.append((t, arm, channel, value))
            fresh = channel in ("joints", "state") and value["stamp_ns"] > restart_ns
            if fresh and arm not in first:
                first[arm] = t
        return set(first) >= set(watched)

    try:
        wait_until(rejoined, 30.0, interval_s=0.1)
    finally:
        time.sleep(0.6)  # a few more streamed commands after the rejoin
        results = client.call("stream_take", _timeout=60.0, name="s")["results"]
    time.sleep(0.5)
    samples.extend(client.call("watch_take")["samples"])
    rejoin = {arm: (t - restart_ns) / 1e9 for arm, t in first.items()}
    after_listening = max(rejoin.values()) - listening_s

    # Latched across the outage, and still.
    if kind.is_arm:
        status = client.call("snapshot", arms=[unit])["arms"][unit][0]
    else:  # the newest state heard (the rejoin waited for one stamped after the restart)
        status = client.call("device_state", unit=unit)["state"]
        assert status["stamp_ns"] > restart_ns, f"{unit}: no state since the restart: {status}"
    assert status["estopped"] and "latched before" in status["stop_reason"], status
    rows = kind.poses(samples, unit)
    assert rows, f"{unit}: no pose recorded"
    spread = max(
        max(r[2][j] for r in rows) - min(r[2][j] for r in rows) for j in range(len(rows[0][2]))
    )
    assert spread <= kind.still_tol, f"{unit} moved {spread:.3f} while latched"

    # No command executed twice.
    written = joint_moves(commands_seen(fleet.lab.log(spy), since_ns), 0)
    twice = {angle: n for angle, n in written.items() if n > 1}
    acked = [round(r["angle_deg"], 3) for r in results if r["reply"]["ok"]]
    failed = [r for r in results if not r["reply"]["ok"]]
    assert not twice, f"executed more than once: {twice}"
    assert all(written[a] == 1 for a in acked), {a: written[a] for a in acked if written[a] != 1}
    return {
        "rejoin": rejoin,
        "listening_s": listening_s,
        "after_listening_s": after_listening,
        "commands": len(results),
        "acked": len(acked),
        "failed": len(failed),
        "written": sum(written.values()),
        "errors": sorted({r["reply"]["error"]["code"] for r in failed}),
        "latched": f"{kind.name} {unit}",
        "spread": spread,
    }


def _report(name: str, figures: dict[str, Any]) -> str:
    rejoin = figures["rejoin"]
    return (
        f"\nrow 3 [{figures['latched']} latched: still latched, spread "
        f"{figures['spread']:.3f}], {name} killed for {OUTAGE_S:g} s and restarted: "
        "joints (states) again after "
        f"{', '.join(f'{a} {s:.2f}' for a, s in sorted(rejoin.items()))} s from its start "
        f"(max {max(rejoin.values()):.2f} s; it listened after "
        f"{figures['listening_s']:.2f} s, so {figures['after_listening_s']:.2f} s after "
        "it listened); "
        f"{figures['commands']} streamed commands: "
        f"{figures['acked']} acknowledged, {figures['failed']} failed {figures['errors']}, "
        f"{figures['written']} written to the arm, none twice"
    )


def _latched(fleet: LabFleet, kind: LabKind, arm: str) -> tuple[LabKind, str]:
    """The unit to latch: ``arm`` for the arm kind, else the lab's device of the kind."""
    return kind, arm if kind.is_arm else kind.units(fleet)[0]


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
def test_a_site_router_restart(lab2: LabFleet, kind: LabKind) -> None:
    latched = _latched(lab2, kind, "a2")
    figures = _restart_router(lab2, "site1", latched, "a1", watched=SITES["site1"])
    print(_report("site router", figures))
    assert figures["after_listening_s"] <= REJOIN_BOUND_S


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
def test_the_central_router_restart(lab2: LabFleet, kind: LabKind) -> None:
    arms = [a for arms in SITES.values() for a in arms]
    figures = _restart_router(lab2, "central", _latched(lab2, kind, "a4"), "a3", watched=arms)
    print(_report("central router", figures))
    assert figures["after_listening_s"] <= REJOIN_BOUND_S


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
def test_the_one_router_restart(lab1: LabFleet, kind: LabKind) -> None:
    latched = _latched(lab1, kind, "a2")
    figures = _restart_router(lab1, "router", latched, "a1", watched=list(lab1.arms))
    print(_report("topology 1 router", figures))
    assert figures["after_listening_s"] <= REJOIN_BOUND_S
