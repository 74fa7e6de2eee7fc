"""Fault matrix, row 1: a fleet stop of 5 moving arms with 0 %, 10 % and 30 % loss and 20 ms of
delay on every link, each way. A stop from the client to an agent crosses four links (the
client's, the router's twice, the arm host's): 20 ms and 10 % per link make 80 ms and 34 % loss
from put to agent, and the same again for the ack.

Each stop is ``fleet estop``'s path (FleetClient.estop: re-put every 100 ms until acked) taken
while every arm moves (a synchronized move through the coordinator). The figure is the time from
the stop's put (its stamp) to the last arm seen still (the agent's ``still_ns``; hosts share
one clock), next to the time the last arm received it and the time the last ack reached the
client (``estop()`` returns; it polls every 100 ms).
"""

from __future__ import annotations

import time
from typing import Any

import pytest

from tests.netlab.checks import percentile, restore
from tests.netlab.fleetlab import LabFleet, RemoteClient

DELAY_MS = 20.0
STOPS_PER_LEVEL = {0.0: 3, 0.10: 5}
GOAL_AT_10_PCT_MS = 500.0
"""The issue's goal: put -> last arm still at 10 % loss."""
BOUND_MS = {0.0: 1000.0, 0.10: 5000.0}
"""What this lab holds to (measured 0.5-0.6 s clean, up to 2.3 s at 10 %: see the README)."""
PARTITION_LIKE_S = 6.0
"""At 30 % the stop is tried this long, then the links heal."""


def _stop_moving_fleet(client: RemoteClient, arms: list[str], n: int) -> dict[str, Any]:
    """Reset, start a synchronized move, stop it while the arms move; the stop's figures."""
    cleared = client.call("reset_wait", _timeout=40.0, timeout_s=30.0)
    assert cleared["clear"], cleared
    angle = 40.0 if n % 2 == 0 else -40.0
    move = {"op": "move_joints", "angles_deg": [angle, 0, 0, 0, 0, 0, 0], "mode": 1}
    moved = client.call("multi", _timeout=30.0, target="all", command=move, sync=True)
    result = client.call("estop", _timeout=60.0, timeout_s=30.0, reason=f"netlab row 1 #{n}")
    return _figures(result, arms) | {"move_ok": moved["reply"]["ok"]}


def _figures(result: dict[str, Any], arms: list[str]) -> dict[str, Any]:
    stamp, acks = result["stamp_ns"], result["acks"]
    missing = [a for a in arms if acks.get(a) is None or acks[a]["still_ns"] is None]
    received = [(a["received_ns"] - stamp) / 1e6 for a in acks.values() if a]
    return {
        "missing": missing,
        "acks": acks,
        "received_ms": max(received, default=float("inf")),
        "still_ms": float("inf")
        if missing
        else max((a["still_ns"] - stamp) / 1e6 for a in acks.values()),
        "returned_ms": (result["returned_ns"] - stamp) / 1e6,
    }


@pytest.mark.parametrize("loss", [0.0, 0.10], ids=["loss0", "loss10"])
def test_every_stop_is_confirmed_by_every_arm_under_loss(lab1: LabFleet, loss: float) -> None:
    client = lab1.clients["client"]
    restore(lab1, client)
    arms = list(lab1.arms)
    try:
        lab1.lab.impair_all(loss=loss, delay_ms=DELAY_MS)
        runs = [_stop_moving_fleet(client, arms, n) for n in range(STOPS_PER_LEVEL[loss])]
    finally:
        lab1.lab.clear()
    still = [r["still_ms"] for r in runs]
    received = ", ".join(f"{r['received_ms']:.0f}" for r in runs)
    line = (
        f"row 1, loss {loss:.0%} + {DELAY_MS:g} ms per link, {len(runs)} stops of 5 moving arms: "
        f"put -> last arm still p50 {percentile(still, 50):.0f} ms, max {max(still):.0f} ms "
        f"({', '.join(f'{s:.0f}' for s in still)}); put -> last arm received max "
        f"{max(r['received_ms'] for r in runs):.0f} ms "
        f"({received}); last ack at the client max "
        f"{max(r['returned_ms'] for r in runs):.0f} ms; moves ok "
        f"{sum(r['move_ok'] for r in runs)}/{len(runs)}"
    )
    print("\n" + line)
    for n, run in enumerate(runs):
        assert not run["missing"], f"stop {n}: not confirmed by {run['missing']}: {run['acks']}"
    assert max(still) <= BOUND_MS[loss], line
    if loss == 0.10 and max(still) > GOAL_AT_10_PCT_MS:
        pytest.xfail(
            f"goal missed: put -> last arm still {max(still):.0f} ms > {GOAL_AT_10_PCT_MS:g} ms "
            "at 10 % loss: TCP retransmission on the way to the agent dominates (see README)"
        )


def test_a_stop_under_30_pct_loss_is_delivered_once_the_links_heal(lab1: LabFleet) -> None:
    """At 30 % per link (51 % per path) the Zenoh sessions do not stay up: TCP retransmits
    with a doubling timeout, the 3 s lease expires, sessions close and reopen, and the
    reopening handshake is lost too. A stop then waits for the links: the client keeps
    re-putting it and the agents act on it when it arrives. The figure is what got through
    in PARTITION_LIKE_S seconds, and how long after healing every arm confirmed."""
    client = lab1.clients["client"]
    restore(lab1, client)
    arms = list(lab1.arms)
    move = {"op": "move_joints", "angles_deg": [-60.0, 0, 0, 0, 0, 0, 0], "mode": 1}
    assert client.call("multi", target="all", command=move, sync=True)["reply"]["ok"]
    try:
        lab1.lab.impair_all(loss=0.30, delay_ms=DELAY_MS)
        lossy = _figures(
            client.call("estop", _timeout=60.0, timeout_s=PARTITION_LIKE_S, reason="row 1 30 %"),
            arms,
        )
    finally:
        lab1.lab.clear()
    healed_ns = time.time_ns()
    after = client.call("estop", _timeout=60.0, timeout_s=30.0, again=True)
    healed = _figures(after, arms)  # the same stop: agents' times from its first arrival
    got = len(arms) - len(lossy["missing"])
    print(
        f"\nrow 1, loss 30 % + {DELAY_MS:g} ms per link: {got}/{len(arms)} arms' still acks "
        f"reached the client within {PARTITION_LIKE_S:g} s; the agents' own times: last arm "
        f"received the stop {healed['received_ms']:.0f} ms and was seen still "
        f"{healed['still_ms']:.0f} ms after the put; after healing every ack arrived within "
        f"{(after['returned_ns'] - healed_ns) / 1e6:.0f} ms"
    )
    assert not healed["missing"], f"after healing, no confirmation from {healed['missing']}"
    if lossy["missing"]:
        pytest.xfail(
            f"at 30 % loss per link only {got}/{len(arms)} arms' confirmations reached the "
            f"client within {PARTITION_LIKE_S:g} s: the Zenoh sessions collapse (see README)"
        )
