"""Sections 7 and 8: a fleet of 1000 simulated arms, and a fleet behind two routers.

Both are real runs of the product's processes on loopback: ``fleet router`` (site routers with
``--listen``/``--connect``), ``fleet sim`` processes (``--no-zenoh``: a real arm is a DDS device;
the fault-injection queryable is a test hook), edge agents ``python -m edge_agent``, and for the
1000 arms also ``fleet coordinator`` and ``fleet viewer`` (no browser). One DDS domain of the
run's own, CycloneDDS on loopback with multicast off (``fleet.d1.dds.cyclonedds_config``), Zenoh
with scouting off and explicit ``tcp/127.0.0.1:<free port>`` endpoints (``fleet.wire.session``).

Relay latency is each ``joints`` sample's ``stamp_ns`` (taken by the agent when it took the
angle report from DDS) to its arrival at a client on the central router (``bench.w_joints``,
every K-th arm). That path holds one Zenoh hop per router plus the agent's work after the stamp,
so it is compared with a raw Zenoh hop (``bench.w_zenoh``, 100 B at 50 Hz) over the same
router(s), measured during the same window under the same load. Whether the relay keeps up:
the samples the client got per arm and second against what the simulators wrote (each ``fleet
sim`` logs its achieved rate at exit), and the latency of the first against the last third of
the window (a relay falling behind shows as growing lag or lost samples; the DDS reader's
keep-last history drops samples before the stamp, so lost samples are the DDS side's sign).
Stops reuse ``bench.w_stop`` (stamp to each arm's ``StopAck.dds_written_ns``).
"""

from __future__ import annotations

import re
import statistics
import time
from pathlib import Path
from typing import Any

from bench.fleet_runs import stops_run
from bench.proc import CLOCK_TICKS, BenchFleet, Worker, cpu_s
from bench.raw import fanout_in
from bench.stats import summary_ms
from fleet.sim.node import FEEDBACK_PERIOD_S
from testkit.harness import free_port

ARMS_PER_PROCESS = 250
"""1000 arms: four ``fleet sim`` processes and four agents, 250 arms each."""
NOMINAL_HZ = 1.0 / statistics.mean(FEEDBACK_PERIOD_S)
PROBE_HZ = 50.0
"""Rate of the raw Zenoh hop measured alongside the relay."""
WARMUP_S = 3.0
_SIM_RATE = re.compile(r"fleet sim: (\d+) reports of (\d+) arms in ([\d.]+) s: ([\d.]+) Hz per arm")


def _busy_s() -> tuple[float, float]:
    """(busy, total) CPU seconds of the whole machine, from /proc/stat (all cores)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = fields[3] + fields[4]
    return (sum(fields) - idle) / CLOCK_TICKS, sum(fields) / CLOCK_TICKS


def _start_arms(
    fleet: BenchFleet, per_process: int, sites: list[str] | None = None
) -> tuple[list[Worker], list[Worker]]:
    """A ``fleet sim`` and an edge agent per group of ``per_process`` arms; with ``sites``, the
    agents of group i join site router ``sites[i % len(sites)]``."""
    sims, agents = [], []
    for i, group in enumerate(fleet.groups(per_process)):
        arms = fleet.arm_args(group)
        sim_argv = ["-m", "fleet.cli.main", "sim", "--no-zenoh", "--seed", str(i), *arms]
        sims.append(fleet.start(f"sim{i}", sim_argv, log_level="INFO"))  # INFO: its rate
        site = ["--endpoint", sites[i % len(sites)]] if sites else []
        agents.append(fleet.start(f"agent{i}", ["-m", "edge_agent", *arms, *site]))
    return sims, agents


def _sim_rates(sims: list[Worker]) -> dict[str, Any]:
    """Stop the simulators and read the rate each logged at exit."""
    rates, lines = [], []
    for sim in sims:
        sim.stop()
        text = sim.log_path.read_text(errors="replace")
        found = _SIM_RATE.search(text)
        if found:
            rates.append(float(found.group(4)))
            lines.append(found.group(0))
    return {"per_arm_hz": min(rates, default=float("nan")), "logged": lines}


def _probe(fleet: BenchFleet, window_s: float, pub_endpoint: str | None) -> tuple[Worker, Worker]:
    """Start a raw Zenoh hop (publisher on ``pub_endpoint`` or the central router, subscriber on
    the central router) that runs through the coming window."""
    sub = fleet.start("probe-sub", ["-m", "bench.w_zenoh", "sub", "--warmup", "10"], piped=True)
    sub.wait_ready()
    argv = ["-m", "bench.w_zenoh", "pub", "--rate-hz", str(PROBE_HZ), "--warmup", "10"]
    argv += ["--count", str(int(window_s * PROBE_HZ))]
    argv += ["--endpoint", pub_endpoint] if pub_endpoint else []
    return sub, fleet.start("probe-pub", argv, piped=True)


def _probe_result(sub: Worker, pub: Worker, window_s: float) -> dict[str, Any]:
    pub.result(timeout_s=window_s + 60.0)
    delays = [delay for delay, _n in sub.finish()["per_put"].values()]
    return summary_ms(delays)


def _relay(got: dict[str, Any], w0: int, w1: int, arms: int) -> dict[str, Any]:
    """Latency (stamp -> client) over the window and per third; samples per arm and second."""
    rows = [r for r in got["received"] if w0 <= r[2] < w1]
    third = (w1 - w0) / 3
    thirds = [[r for r in rows if w0 + k * third <= r[2] < w0 + (k + 1) * third] for k in range(3)]
    per_s = [len(t) / arms / (third / 1e9) for t in thirds]
    first, last = (summary_ms([r[2] - r[3] for r in t]) for t in (thirds[0], thirds[2]))
    return {
        **summary_ms([r[2] - r[3] for r in rows]),
        "arms_sampled": arms,
        "never_heard": got["never_heard"],
        "rate_per_arm_hz": [round(x, 2) for x in per_s],
        "first_third": first,
        "last_third": last,
        "lag_growth": round(last["p50_ms"] / first["p50_ms"], 2) if first["p50_ms"] else None,
    }


def _snapshot(
    watched: dict[str, Worker],
) -> tuple[dict[str, float], tuple[float, float], float, int]:
    """CPU seconds of each watched process, the machine's, and the monotonic and wall clocks."""
    cpu = {name: cpu_s(worker.pid) for name, worker in watched.items()}
    return cpu, _busy_s(), time.monotonic(), time.time_ns()


def _window(
    fleet: BenchFleet, watched: dict[str, Worker], window_s: float, every: int, probe_ep: str | None
) -> dict[str, Any]:
    """The relay client and the probe through ``window_s``, with every watched process's CPU."""
    client_argv = ["-m", "bench.w_joints", "--every", str(every), "--wait-all", "--max-s", "300"]
    client = fleet.start("joints-client", client_argv, piped=True)
    client.wait_ready(timeout_s=200.0)
    probe_sub, probe_pub = _probe(fleet, window_s, probe_ep)
    time.sleep(WARMUP_S)
    watched = {**watched, "client": client}
    c0, b0, t0, w0 = _snapshot(watched)
    time.sleep(window_s)
    c1, b1, t1, w1 = _snapshot(watched)
    got = client.finish(timeout_s=120.0)
    wall = t1 - t0
    arms = got["arms"]
    return {
        "window_s": round(wall, 1),
        "relay": _relay(got, w0, w1, arms),
        "probe_hop": _probe_result(probe_sub, probe_pub, window_s),
        "cpu_pct": {n: round(100.0 * (c1[n] - c0[n]) / wall, 1) for n in watched},
        "machine_busy_pct": round(100.0 * (b1[0] - b0[0]) / (b1[1] - b0[1]), 1),
        "alive": {n: w.alive() for n, w in watched.items()},
    }


def thousand_arms(arms: int, window_s: float, stops: int) -> dict[str, Any]:
    """``arms`` simulated arms at ~10 Hz over agents of 250 arms, with the coordinator and the
    viewer: relay, lag, per-process CPU, then fleet stops to the last arm."""
    with BenchFleet(arms, f"scale{arms}") as fleet:
        started = time.monotonic()
        router = fleet.start_router()
        sims, agents = _start_arms(fleet, ARMS_PER_PROCESS)
        coordinator = fleet.start("coordinator", ["-m", "fleet.cli.main", "coordinator"])
        viewer_argv = ["-m", "fleet.cli.main", "viewer", "--port", str(free_port())]
        viewer = fleet.start("viewer", viewer_argv)
        viewer.wait_log("d1-fleet viewer: http", timeout_s=120.0)
        viewer_ready_s = time.monotonic() - started
        watched = {"router": router, "coordinator": coordinator, "viewer": viewer}
        watched |= {w.name: w for w in (*agents, *sims)}
        out = _window(fleet, watched, window_s, every=10, probe_ep=None)
        out["startup_s"] = round(time.monotonic() - started - out["window_s"], 1)
        out["viewer_ready_s"] = round(viewer_ready_s, 1)
        out["stop"] = stops_run(fleet, stops, timeout_s=5.0)
        out["sim"] = _sim_rates(sims)
    cpu = out["cpu_pct"]
    out |= {
        "arms": arms,
        "agents": len(agents),
        "sims": len(sims),
        "nominal_hz": round(NOMINAL_HZ, 2),
        "agents_cpu_pct": round(sum(cpu[w.name] for w in agents), 1),
        "sims_cpu_pct": round(sum(cpu[w.name] for w in sims), 1),
    }
    return out


def two_routers(arms: int, window_s: float, stops: int, fanout_puts: int) -> dict[str, Any]:
    """A central router, two site routers joined to it, agents of 25 arms on the sites, and the
    clients on the central router: raw fan-out, then relay and stops through both routers."""
    with BenchFleet(arms, f"routers{arms}") as fleet:
        central = fleet.start_router("central")
        sites = [free_port(), free_port()]
        site_eps = [f"tcp/127.0.0.1:{port}" for port in sites]
        routers = {"central": central}
        for i, port in enumerate(sites):
            routers[f"site{i}"] = fleet.start_router(f"site{i}", port, (fleet.endpoint,))
        time.sleep(1.0)  # the sites join the central router (they retry until they have)
        fanout = fanout_in(fleet, 100, fanout_puts, 20.0, stop_qos=True, pub_endpoint=site_eps[0])
        fanout.pop("samples_ns")
        sims, agents = _start_arms(fleet, 25, site_eps)
        watched = {**routers, **{w.name: w for w in (*agents, *sims)}}
        out = _window(fleet, watched, window_s, every=1, probe_ep=site_eps[0])
        out["stop"] = stops_run(fleet, stops)
        out["sim"] = _sim_rates(sims)
    return {**out, "arms": arms, "agents": len(agents), "site_routers": 2, "fanout_100": fanout}


def run(quick: bool) -> dict[str, Any]:
    """Both sections (see ``bench/__main__.py`` for running one alone)."""
    return {"thousand": run_thousand(quick), "two_routers": run_two_routers(quick)}


def run_thousand(quick: bool) -> dict[str, Any]:
    """Section 7: 1000 arms."""
    # 20 s and 6 stops keep the whole of make bench under 10 minutes (the start takes 1-3).
    return thousand_arms(1000, 12.0 if quick else 20.0, 4 if quick else 6)


def run_two_routers(quick: bool) -> dict[str, Any]:
    """Section 8: 100 arms behind two site routers."""
    return two_routers(100, 8.0 if quick else 15.0, 6 if quick else 12, 40 if quick else 150)
