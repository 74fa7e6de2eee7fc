"""Fault matrix, row 5: consumers that stop reading. On the viewer host, one consumer of every
arm's joints and status and every device's state (what the viewer subscribes to) is frozen
(SIGSTOP: a hung viewer, or `fleet status --watch` suspended with Ctrl-Z) and another is slow
(0.2 s in its callback for every sample). A load generator on the viewer host publishes a large
fleet's status traffic (8 KB at 250 Hz, 2 MB/s, with the agents' status QoS: DROP, DATA_HIGH, on
the status key of an arm that does not exist) and the viewer host's TCP receive buffer is capped
at 64 KB, so what takes 36-41 s with 5 arms alone (measured in 60 s runs) happens within
seconds.

Asserted for every kind (``LAB_KINDS``: the five arms, the Dex1-1 on a1, the G1; one episode,
each kind's tests read its own units' figures): the relay of its units is neither stalled nor
slowed, a stop put during a stall (if one came) still gets through, stops after the episode
are as fast as before it; and the resident memory of the router and of an agent stays bounded
over FROZEN_S, the consumers and the fleet survive.

Product bug, fixed: a BLOCK sample for a subscriber whose queue is full made the Zenoh router
wait up to ``wait_before_close`` (5 s by default) before it dropped that session, routing
nothing else meanwhile: every agent's joints, status and stop acks, and the client's stops,
were held up for 5-10 s (once per stuck session) for everyone. Now ``status`` and ``diag`` are
DROP (they repeat) and the fleet's routers wait at most 0.5 s (``ROUTER_BLOCK_WAIT_S``).
"""

from __future__ import annotations

import re
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from testkit.harness import wait_until
from testkit.load import xfail_if_overloaded, xfail_if_shared
from tests.netlab.checks import percentile, restore
from tests.netlab.fleetlab import LabFleet, RemoteClient
from tests.netlab.labkinds import LAB_KIND_IDS, LAB_KINDS, LabKind
from tests.netlab.rowreport import RowReport

ROW = "5"
BASELINE_S = 4.0
FROZEN_S = 25.0
"""How long the consumers stay (the memory window; before the fix the stall came 22-41 s after
the freeze)."""
STALL_S = 1.0
"""No sample of a kind's units for this long is a stall (an arm's joints come at 10 Hz, a G1's
state at 10 Hz, a gripper's at 50 Hz)."""
STALL_NS = int(STALL_S * 1e9)
LOAD = {"rate_hz": 250.0, "size": 8000}
STOPS = 2
RELAY_P99_SLACK_MS = 20.0
"""The relay's p99 with the consumers may exceed the baseline's by this much (2-core host)."""
SHARED_SPIKES = (
    "in make test every kind's relay showed spikes of 60-370 ms at the same moments, in 6 of 6 "
    "fresh-clone runs (2026-11-27), once in the baseline without the frozen consumer too (p99 "
    "103 ms) and once at load 2.8 (no load XFAIL); the row alone, after the whole lab, and "
    "beside busy loops at nice 0 or 5 showed none (worst 8-19 ms, p99 2-9 ms, 8 runs): the "
    "relay p99 is asserted in a lab run alone"
)
"""Why the relay's p99 is not asserted while other workers' tests share the host (a stall,
no sample for ``STALL_S``, is asserted everywhere)."""
STOP_SLACK_MS = 100.0
RSS_GROWTH_MB = {"router": 64.0, "agent-a1": 10.0}
"""The router allocates its transmission queues for the two consumers' sessions at once
(+36 MB here, then +11 MB once, flat after: 82 MB after 60 s as after 20 s)."""


def _rss_mb(pid: int) -> float:
    text = Path(f"/proc/{pid}/status").read_text()
    found = re.search(r"VmRSS:\s+(\d+) kB", text)
    return int(found.group(1)) / 1024 if found else 0.0


def _channel(kind: LabKind) -> str:
    """What a consumer of the kind's units receives most often: an arm's joints, a device's
    state."""
    return "joints" if kind.is_arm else "state"


def _relay_ms(samples: list[Any], kind: LabKind, units: list[str]) -> list[float]:
    channel = _channel(kind)
    return [
        (t - value["stamp_ns"]) / 1e6
        for t, unit, c, value in samples
        if c == channel and unit in units
    ]


def _timeline(samples: list[Any], kind: LabKind, units: list[str], step_s: float = 2.0) -> str:
    """The worst relay delay of the kind's units in each ``step_s`` window, by arrival time."""
    channel = _channel(kind)
    rows = [(t, (t - v["stamp_ns"]) / 1e6) for t, u, c, v in samples if c == channel and u in units]
    if not rows:
        return "-"
    start = min(t for t, _d in rows)
    worst: dict[int, float] = {}
    for t, delay in rows:
        slot = int((t - start) / 1e9 / step_s)
        worst[slot] = max(worst.get(slot, 0.0), delay)
    return " ".join(f"{worst.get(i, float('nan')):.0f}" for i in range(max(worst) + 1))


def _relay_text(values: list[float]) -> str:
    return f"p50 {percentile(values, 50):.1f} / p99 {percentile(values, 99):.1f} ms"


def _stop_figures(runs: list[dict[str, Any]], labels: list[str]) -> list[dict[str, float]]:
    """Per stop, over the units named ``labels`` (as the acks name them): the last receipt and
    the last confirmation, from the stop's put."""
    return [
        {
            "received_ms": max((r["acks"][a]["received_ns"] - r["stamp_ns"]) / 1e6 for a in labels),
            "still_ms": max((r["acks"][a]["still_ns"] - r["stamp_ns"]) / 1e6 for a in labels),
        }
        for r in runs
    ]


def _stops_text(figures: list[dict[str, float]]) -> str:
    return (
        f"received max {max(r['received_ms'] for r in figures):.0f} ms, confirmed max "
        f"{max(r['still_ms'] for r in figures):.0f} ms"
    )


def _stops(client: RemoteClient, labels: list[str]) -> list[dict[str, Any]]:
    """STOPS fleet stops, each confirmed by every unit (``labels``, as the acks name them)."""
    out = []
    for n in range(STOPS):
        cleared = client.call("reset_wait", _timeout=40.0, timeout_s=30.0)
        assert cleared["clear"], cleared
        result = client.call("estop", timeout_s=5.0, reason=f"row 5 #{n}")
        acks = result["acks"]
        missing = [a for a in labels if not acks.get(a) or not acks[a]["still_ns"]]
        assert not missing, f"stop {n} not confirmed by {missing}: {acks}"
        out.append(result)
    return out


def _units(lab: LabFleet) -> dict[str, list[str]]:
    """Kind name -> the lab's units of that kind."""
    return {kind.name: kind.units(lab) for kind in LAB_KINDS}


def _labels(lab: LabFleet, kinds: tuple[LabKind, ...] = LAB_KINDS) -> list[str]:
    return [kind.label(u) for kind in kinds for u in kind.units(lab)]


@pytest.fixture(scope="module")
def frozen_run(lab1: LabFleet) -> Iterator[dict[str, Any]]:
    """The baseline, then FROZEN_S seconds with the frozen and the slow consumer; every kind's
    units in it (``LAB_KINDS``), each kind's tests read their own figures."""
    client = lab1.clients["client"]
    restore(lab1, client)
    units, labels = _units(lab1), _labels(lab1)
    lab1.lab.sysctl("viewer", "net.ipv4.tcp_rmem=4096 16384 65536")
    watched = {
        "router": lab1.lab.harness.processes["router"].pid,
        "agent-a1": lab1.lab.harness.processes["agent-a1"].pid,
    }
    client.call("watch_start")
    loadgen = lab1.start_client("loadgen", "viewer", [lab1.lab.hosts["router"].endpoint])
    loadgen.call("load_start", for_s=BASELINE_S + FROZEN_S + 25.0, **LOAD)
    client.call("watch_take")
    time.sleep(BASELINE_S)
    base_stops = _stops(client, labels)
    base_samples = client.call("watch_take")["samples"]
    rss: dict[str, list[float]] = {name: [_rss_mb(pid)] for name, pid in watched.items()}

    inventory = lab1.inventory("consumer", [lab1.lab.hosts["router"].endpoint])
    consumer = ["-m", "tests.netlab.consumer", str(inventory)]
    frozen = lab1.lab.start("consumer-frozen", "viewer", consumer)
    slow = lab1.lab.start("consumer-slow", "viewer", [*consumer, "--slow-s", "0.2"])
    try:
        for name in ("consumer-frozen", "consumer-slow"):
            wait_until(lambda n=name: "ready" in lab1.lab.log(n), 20.0)
        frozen.send_signal(signal.SIGSTOP)
        client.call("watch_take")
        started = time.monotonic()
        frozen_samples: list[Any] = []
        last_ns = dict.fromkeys(units, time.time_ns())
        stall: dict[str, Any] | None = None
        while time.monotonic() - started < FROZEN_S:
            time.sleep(1.0)
            frozen_samples += client.call("watch_take")["samples"]
            for name, pid in watched.items():
                rss[name].append(_rss_mb(pid))
            for kind in LAB_KINDS:
                channel, mine = _channel(kind), units[kind.name]
                real = [t for t, u, c, _v in frozen_samples if c == channel and u in mine]
                last_ns[kind.name] = max(real, default=last_ns[kind.name])
            now_ns = time.time_ns()
            silent = {k: (now_ns - t) / 1e9 for k, t in last_ns.items() if t < now_ns - STALL_NS}
            if stall is None and silent:
                # The relay stalls: does a stop still get through, and its acks back?
                result = client.call("estop", timeout_s=12.0, reason="row 5, during a stall")
                stall = {"at_s": time.monotonic() - started, "silent_s": silent, **result}
        frozen_stops = _stops(client, labels)
        frozen_samples += client.call("watch_take")["samples"]
        for name, pid in watched.items():
            rss[name].append(_rss_mb(pid))
        consumers_alive = slow.poll() is None and frozen.poll() is None
    finally:
        frozen.send_signal(signal.SIGCONT)
        lab1.lab.stop("consumer-slow")
        lab1.lab.stop("consumer-frozen")
    run = {
        "base_samples": base_samples,
        "frozen_samples": frozen_samples,
        "base_stops": base_stops,
        "frozen_stops": frozen_stops,
        "rss": rss,
        "growth": {name: max(series) - series[0] for name, series in rss.items()},
        "consumers_alive": consumers_alive,
        "stall": stall,
        "window_s": time.monotonic() - started,
    }
    arms, arm = units["arm"], LAB_KINDS[0]
    print(
        f"\nrow 5, a frozen + a slow consumer of every joints/status/state key for "
        f"{run['window_s']:.0f} s under 2 MB/s of status traffic: stops "
        f"{_stops_text(_stop_figures(base_stops, labels))} without, "
        f"{_stops_text(_stop_figures(frozen_stops, labels))} with; RSS "
        + ", ".join(
            f"{n} {s[0]:.0f} -> {max(s):.0f} MB (+{run['growth'][n]:.1f})" for n, s in rss.items()
        )
        + f"; arms' relay {_relay_text(_relay_ms(base_samples, arm, arms))} without, "
        f"{_relay_text(_relay_ms(frozen_samples, arm, arms))} with; worst per 2 s (ms, nan: "
        f"no sample): {_timeline(frozen_samples, arm, arms)}; stall: {stall}"
    )
    yield run
    cleared = client.call("reset_wait", _timeout=40.0, timeout_s=30.0)
    assert cleared["clear"], cleared


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
def test_frozen_and_slow_consumers_delay_no_stop_and_grow_no_memory(
    lab1: LabFleet, frozen_run: dict[str, Any], kind: LabKind, row_report: RowReport
) -> None:
    run = frozen_run
    labels = [kind.label(u) for u in kind.units(lab1)]
    base, frozen = (_stop_figures(run[k], labels) for k in ("base_stops", "frozen_stops"))
    row_report(
        f"a frozen + a slow consumer for {run['window_s']:.0f} s under 2 MB/s of status "
        f"traffic: stops of the {kind.name} units {_stops_text(base)} without, "
        f"{_stops_text(frozen)} with; RSS "
        + ", ".join(f"{n} +{grew:.1f} MB" for n, grew in run["growth"].items())
        + f"; consumers alive {run['consumers_alive']}",
        f"router RSS growth <= {RSS_GROWTH_MB['router']:g} MB, agent <= "
        f"{RSS_GROWTH_MB['agent-a1']:g} MB; stops as fast as without (+{STOP_SLACK_MS:g} ms)",
        {"base_stops": base, "frozen_stops": frozen, "growth": run["growth"]}
        | {"window_s": run["window_s"]},
    )
    assert run["consumers_alive"]
    for name, grew in run["growth"].items():
        assert grew <= RSS_GROWTH_MB[name], f"{name} grew {grew:.1f} MB: {run['rss'][name]}"
    slower = [
        what
        for what in ("received_ms", "still_ms")
        if max(r[what] for r in frozen) > max(r[what] for r in base) + STOP_SLACK_MS
    ]
    xfail_if_overloaded(slower)
    assert not slower, f"stops slower with the frozen consumer ({slower}): {base} / {frozen}"


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
def test_a_frozen_consumer_does_not_delay_the_relay(
    lab1: LabFleet, frozen_run: dict[str, Any], kind: LabKind, row_report: RowReport
) -> None:
    units = kind.units(lab1)
    base = _relay_ms(frozen_run["base_samples"], kind, units)
    frozen = _relay_ms(frozen_run["frozen_samples"], kind, units)
    timeline = _timeline(frozen_run["frozen_samples"], kind, units)
    stall = frozen_run["stall"]
    stalled = stall is not None and kind.name in stall["silent_s"]
    row_report(
        f"{kind.name} relay ({_channel(kind)}) {_relay_text(base)} without, "
        f"{_relay_text(frozen)} with; worst relay per 2 s (ms): {timeline}; "
        f"{'a stall' if stalled else 'no stall'}",
        f"no relay stall ({STALL_S:g} s without a sample); relay p99 within "
        f"{RELAY_P99_SLACK_MS:g} ms of the baseline (in a lab run alone; beside other test "
        "workers a miss is an XFAIL naming them)",
        {"p99_ms": [percentile(base, 99), percentile(frozen, 99)], "stall": stalled},
    )
    assert base and frozen, f"no {kind.name} samples: {len(base)} without, {len(frozen)} with"
    assert not stalled, f"the {kind.name} relay stalled: {stall}"
    slow = percentile(frozen, 99) > percentile(base, 99) + RELAY_P99_SLACK_MS
    xfail_if_overloaded(["relay p99"] if slow else [])
    xfail_if_shared(["relay p99"] if slow else [], SHARED_SPIKES)
    assert not slow, (
        f"{kind.name} relay p99 {percentile(frozen, 99):.0f} ms with the frozen consumer, "
        f"{percentile(base, 99):.0f} ms without; worst per 2 s: {timeline}"
    )


@pytest.mark.parametrize("kind", LAB_KINDS, ids=LAB_KIND_IDS)
def test_a_frozen_consumer_does_not_delay_a_stop(
    lab1: LabFleet, frozen_run: dict[str, Any], kind: LabKind, row_report: RowReport
) -> None:
    stall = frozen_run["stall"]
    labels = [kind.label(u) for u in kind.units(lab1)]
    if stall is None:
        row_report(
            "no relay stall, so no stop during one",
            "a stop put during a relay stall received <= 500 ms and acked <= 1 s",
            {"stall": None},
        )
        return
    acks = stall["acks"]
    received = [(acks[a]["received_ns"] - stall["stamp_ns"]) / 1e6 for a in labels if acks.get(a)]
    received_ms = max(received) if len(received) == len(labels) else float("inf")
    acked_ms = (stall["returned_ns"] - stall["stamp_ns"]) / 1e6
    row_report(
        f"the relay stalled {stall['at_s']:.0f} s after the freeze (silent: {stall['silent_s']}); "
        f"a stop then: received by the last {kind.name} unit {received_ms:.0f} ms after the "
        f"put, every ack at the client after {acked_ms:.0f} ms",
        "a stop put during a relay stall received <= 500 ms and acked <= 1 s",
        {"stall_received_ms": received_ms, "stall_ack_ms": acked_ms},
    )
    assert received_ms <= 500.0, stall
    assert acked_ms <= 1000.0, stall
