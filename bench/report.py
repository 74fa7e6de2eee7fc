"""The benchmark's table: every figure with its goal and PASS/FAIL, as Markdown.

A run of some sections only (``python -m bench --only ...``) gets the rows and goals of those.

Latency goals are ratios against the raw hops measured in the same run; a goal is never
loosened here: a missed goal prints FAIL with the figure.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import Any

from bench.stats import ratio

Row = tuple[str, str, str, str, str, str]
"""(measure, p50 or value, p99, ratio, goal, result)."""


def _ms(value: float) -> str:
    return "n/a" if value is None or math.isnan(value) else f"{value:.2f} ms"


def _verdict(ok: bool | None) -> str:
    return "n/a" if ok is None else ("PASS" if ok else "**FAIL**")


def _lat_row(name: str, lat: dict[str, Any]) -> Row:
    return (name, _ms(lat["p50_ms"]), _ms(lat["p99_ms"]), "", "", "")


ISSUE7 = ("raw", "relay", "fleet")
"""The sections the first goals compare with each other."""


COMMAND_RATIO = 1.15
"""Command round trip p50 over its four raw hops (2 DDS + 2 Zenoh) (was 1.25)."""
STOP_FANOUT_RATIO = 1.5
"""Stop to the last of 100 arms p99 over the raw fan-out p99 (was 2)."""
ONE_ARM_CPU_PCT = 0.5
"""The agent of one arm at 10 Hz, % of a core."""
GRIPPER_CPU_PCT = 3.0
"""The agent serving one Dex1-1 at 500 Hz, % of a core."""
ONE_CORE_CPU_RATIO = 1.0
"""One agent serving a D1 and its Dex1-1 uses no more CPU than two agent processes."""
DEVICE_STOP_FLOOD_MS = 500.0
"""A flood on a device's command key never delays its stop beyond this."""
VIEWER_CPU_PCT = 15.0
"""The viewer at 50 arms at 10 Hz, % of a core (and with a G1 drawn too)."""
VIEWER_G1 = "50+g1"
"""The viewer section's entry of the run with a G1 (bench/viewer_cpu.py); the others are arm
counts."""


def goals(r: dict[str, Any]) -> list[dict[str, Any]]:
    """Each goal with its figure, limit and verdict (also saved in the JSON)."""
    out: list[dict[str, Any]] = []

    def add(name: str, figure: float, limit: float, unit: str) -> None:
        ok = None if math.isnan(figure) or math.isnan(limit) else figure <= limit
        out.append({"goal": name, "figure": figure, "limit": limit, "unit": unit, "ok": ok})

    if all(k in r for k in ISSUE7):
        _issue7_goals(r, add)
    viewer50 = r.get("viewer", {}).get("50", math.nan)
    if "viewer" in r:
        add("viewer CPU, 50 arms at 10 Hz (% of a core)", viewer50, VIEWER_CPU_PCT, "%")
    g1 = r.get("viewer", {}).get(VIEWER_G1)
    if g1 is not None:
        add(f"viewer CPU, 50 arms and a G1 at {g1['g1_relay_hz']:g} Hz (% of a core)",
            g1["viewer_cpu_percent_of_a_core"], VIEWER_CPU_PCT, "%")  # fmt: skip
    if "contact" in r:
        _contact_goals(r["contact"], add)
    if "scale" in r:
        _scale_goals(r["scale"], add)
    if "routers" in r:
        _routers_goals(r["routers"], add)
    if "devices" in r:
        grip = r["devices"]["gripper_500"]
        add("gripper relay, 1 gripper at 500 Hz (% of a core)", grip["agent_cpu_pct"],
            GRIPPER_CPU_PCT, "%")  # fmt: skip
    if "onecore" in r:
        core = r["onecore"]
        ratio_ = core["arm_and_gripper"]["cpu_ratio_one_to_two"]
        add("one agent for a D1 + its Dex1-1 at 500 Hz, CPU over two processes",
            math.nan if ratio_ is None else ratio_, ONE_CORE_CPU_RATIO, "x")  # fmt: skip
        flood = core["device_stop_under_flood"]["received"]
        add("device stop under a command-key flood, p99 (ms)", flood.get("p99_ms", math.nan),
            DEVICE_STOP_FLOOD_MS, "ms")  # fmt: skip
    return out


def _contact_goals(families: dict[str, Any], add: Callable[[str, float, float, str], None]) -> None:
    """Each goal over every dynamics family (the worst family's figure)."""
    rows = {name: row for name, row in families.items() if name != "per method"}

    def worst(config: str, figure: Callable[[dict[str, float]], float]) -> float:
        return max(figure(row[config]) for row in rows.values())

    def missed(x: dict[str, float]) -> float:
        return 100.0 - min(x["stall_recall"], x["grip_recall"], x["push_recall"])

    table: tuple[tuple[str, str, Callable[[dict[str, float]], float], float, str], ...] = (
        ("uncalibrated: false alarms in free motion", "none", lambda x: x["false_alarms"], 0, ""),
        ("uncalibrated: force limits in free motion", "none", lambda x: x["free_force_limits"],
         0, ""),
        ("uncalibrated: stalls missed (recall >= 95 %)", "none",
         lambda x: 100.0 - x["stall_recall"], 5, "%"),
        ("calibrated: contacts missed (recall >= 99 %, worst kind)", "calibrated", missed, 1, "%"),
        ("calibrated: false alarms in free motion", "calibrated", lambda x: x["false_alarms"],
         0, ""),
        ("calibrated: force limits in free motion", "calibrated",
         lambda x: x["free_force_limits"], 0, ""),
        ("calibrated: detection delay p95 <= 300 ms", "calibrated", lambda x: x["p95_ms"],
         300, "ms"),
    )  # fmt: skip
    for name, config, figure, limit, unit in table:
        add(f"contact, {name} (worst family)", worst(config, figure), float(limit), unit)


def _stop_p99(stop: dict[str, Any]) -> float:
    """p99 to the last arm's DDS write; infinite when a stop was not acked by every arm."""
    return math.inf if stop["incomplete_stops"] else stop["last_written"]["p99_ms"]


def _keeps_up(run: dict[str, Any]) -> tuple[float, bool]:
    """(share of the simulators' reports relayed in the last third, lag growth <= 1.5 x)."""
    relay = run["relay"]
    share = relay["rate_per_arm_hz"][-1] / run["sim"]["per_arm_hz"]
    return round(share, 3), (relay["lag_growth"] or math.inf) <= 1.5


def _scale_goals(run: dict[str, Any], add: Any) -> None:
    relay, hop = run["relay"], run["probe_hop"]
    share, _flat = _keeps_up(run)
    add("1000 arms: reports relayed in the last third (>= 95 %)", 100 * (1 - share), 5.0, "% lost")
    add("1000 arms: lag growth, last / first third p50 (<= 1.5 x)", relay["lag_growth"] or math.inf,
        1.5, "x")  # fmt: skip
    add(
        "1000 arms: relay p50 <= 2 x raw Zenoh hop alongside",
        relay["p50_ms"],
        2 * hop["p50_ms"],
        "ms",
    )
    add("1000 arms: stop to the last arm p99 <= 50 ms", _stop_p99(run["stop"]), 50.0, "ms")
    add("1000 arms: coordinator (% of a core)", run["cpu_pct"]["coordinator"], 10.0, "%")
    viewer = run["cpu_pct"]["viewer"] if run["alive"]["viewer"] else math.inf
    add("1000 arms: viewer (% of a core; alive at the end)", viewer, 50.0, "%")


def _routers_goals(run: dict[str, Any], add: Any) -> None:
    relay, hop, fan = run["relay"], run["probe_hop"], run["fanout_100"]
    add(
        "two routers: relay p50 <= 1.1 x raw hop over them",
        relay["p50_ms"],
        1.1 * hop["p50_ms"],
        "ms",
    )
    add("two routers: stop to last of 100 arms p99 <= 2 x raw fan-out p99", _stop_p99(run["stop"]),
        2 * fan["p99_ms"], "ms")  # fmt: skip


def _issue7_goals(r: dict[str, Any], add: Any) -> None:
    raw, relay, fleet = r["raw"], r["relay"], r["fleet"]
    dds, zen = raw["dds_hop"]["p50_ms"], raw["zenoh_hop"]["p50_ms"]
    hops = dds + zen
    for rate in ("10", "100"):
        lat = relay[f"1x{rate}"]["latency"]
        add(f"relay p50 at {rate} Hz <= 1.1 x (DDS + Zenoh hop)", lat["p50_ms"], 1.1 * hops, "ms")
    for rate in ("10", "100"):
        add(f"relay p99 at {rate} Hz <= 3 ms", relay[f"1x{rate}"]["latency"]["p99_ms"], 3.0, "ms")
    add(
        f"command p50 <= {COMMAND_RATIO:g} x (2 DDS + 2 Zenoh hops)",
        fleet["command"]["p50_ms"],
        COMMAND_RATIO * 2 * hops,
        "ms",
    )
    stop99 = fleet["stop_100"]["last_written"]["p99_ms"]
    fan99 = raw["zenoh_fanout_100"]["p99_ms"]
    add(
        f"stop to last of 100 arms p99 <= {STOP_FANOUT_RATIO:g} x raw fan-out p99",
        stop99,
        STOP_FANOUT_RATIO * fan99,
        "ms",
    )
    add("stop to last of 100 arms p99 <= 50 ms", stop99, 50.0, "ms")
    big = relay["100x10"]
    add("agent CPU per relayed message (100 arms, 10 Hz)", big["agent_cpu_us_per_msg"], 60.0, "us")
    add("agent CPU, 100 arms at 10 Hz (% of a core)", big["agent_cpu_pct"], 6.0, "%")
    one = relay["1x10"]
    add("agent CPU, 1 arm at 10 Hz (% of a core)", one["agent_cpu_pct"], ONE_ARM_CPU_PCT, "%")
    add("coordinator CPU with 100 arms (% of a core)", big["coordinator_cpu_pct"], 5.0, "%")
    rss0, rss1 = big["coordinator_rss_mb"]
    add(
        f"coordinator RSS growth over {big['window_s']:g} s (flat: < 1 MiB)",
        rss1 - rss0,
        1.0,
        "MiB",
    )


def rows(r: dict[str, Any]) -> list[Row]:
    """The table's rows (of the sections this run has)."""
    table = _issue7_rows(r) if all(k in r for k in ISSUE7) else []
    table += _viewer_rows(r.get("viewer", {}))
    if "scale" in r:
        table += _scale_rows(r["scale"])
    if "routers" in r:
        table += _routers_rows(r["routers"])
    if "devices" in r:
        table += _devices_rows(r["devices"])
    if "onecore" in r:
        table += _onecore_rows(r["onecore"])
    if "ros2" in r:
        table += _ros2_rows(r["ros2"])
    return table


def _viewer_rows(r: dict[str, Any]) -> list[Row]:
    """One row per fleet size, then the run with a G1 against the 50 arms of this run."""
    table: list[Row] = []
    for arms, pct in r.items():
        if arms == VIEWER_G1:
            continue
        ok = pct <= VIEWER_CPU_PCT if arms == "50" else None
        table.append((f"viewer CPU, {arms} arms at 10 Hz", f"{pct:g} % core", "", "",
                      "<= 15 %" if arms == "50" else "(growth)", _verdict(ok)))  # fmt: skip
    g1 = r.get(VIEWER_G1)
    if g1 is not None:
        pct = g1["viewer_cpu_percent_of_a_core"]
        table.append((f"viewer CPU, 50 arms and a G1 at {g1['g1_relay_hz']:g} Hz",
                      f"{pct:g} % core", "", f"{ratio(pct, r.get('50', math.nan))} x 50 arms",
                      f"<= {VIEWER_CPU_PCT:g} %", _verdict(pct <= VIEWER_CPU_PCT)))  # fmt: skip
    return table


def _onecore_rows(r: dict[str, Any]) -> list[Row]:
    pair = r["arm_and_gripper"]
    one, two, ratio_ = pair["one"], pair["two"], pair["cpu_ratio_one_to_two"]
    flood = r["device_stop_under_flood"]
    received, written = flood["received"], flood["written"]
    ok_ratio = None if ratio_ is None else ratio_ <= ONE_CORE_CPU_RATIO
    ok_flood = received.get("p99_ms", math.inf) <= DEVICE_STOP_FLOOD_MS
    return [
        ("D1 (10 Hz) + its Dex1-1 (500 Hz): agent CPU, one process / two",
         f"{one['agent_cpu_pct']:g} % core", f"{two['agent_cpu_pct']:g} % core",
         f"{ratio_} x; gripper {one['gripper_zenoh_rate_hz']:g} / "
         f"{two['gripper_zenoh_rate_hz']:g} Hz on Zenoh",
         f"<= {ONE_CORE_CPU_RATIO:g} x", _verdict(ok_ratio)),
        (f"device stop under a command-key flood ({flood['flood_queries']} queries), "
         f"stamp -> received (n={received.get('n', 0)})", _ms(received.get("p50_ms")),
         _ms(received.get("p99_ms")),
         f"DDS written p99 {_ms(written.get('p99_ms'))}",
         f"<= {DEVICE_STOP_FLOOD_MS:g} ms", _verdict(ok_flood)),
    ]  # fmt: skip


def _ros2_rows(r: dict[str, Any]) -> list[Row]:
    """fleet ros2: joint_states over the joints key, and its CPU."""
    p50, p95 = r["added_ms_p50"], r["added_ms_p95"]
    ok = p50 is not None and p50 <= 2.0 and r["cpu_pct"] <= 3.0
    floor = r.get("floor") or {}
    load = r.get("load_avg_1m_5m")
    extra = f"; no-op relay {_ms(floor.get('added_ms_p50'))}" if floor else ""
    extra += f"; load {load[0]:g}" if load else ""
    return [
        (f"ROS 2 joint_states added latency over joints, {r['arms']} arms at "
         f"{r['rate_hz']:g} Hz (n={r['samples']}, lost {r['lost']})",
         _ms(p50), _ms(p95), f"fleet ros2 {r['cpu_pct']:.1f} % core{extra}",
         "p50 <= 2 ms, <= 3 % core", _verdict(ok)),
    ]  # fmt: skip


def _devices_rows(r: dict[str, Any]) -> list[Row]:
    grip = r["gripper_500"]
    lat = grip["latency"]
    rates = (f"DDS {grip['dds_rate_hz']:g} Hz -> Zenoh {grip['zenoh_rate_hz']:g} Hz "
             f"(configured {grip['relay_hz']:g})")  # fmt: skip
    ok = grip["agent_cpu_pct"] <= GRIPPER_CPU_PCT
    busiest = list(grip["agent_threads_pct"].items())[:4]
    threads = ", ".join(f"{name} {pct:g}" for name, pct in busiest)
    return [
        (f"gripper relay CPU, 1 Dex1-1 at {grip['rate_hz']:g} Hz (devices agent)",
         f"{grip['agent_cpu_us_per_sample']:g} us/DDS sample", f"{grip['agent_cpu_pct']:g} % core",
         "", f"<= {GRIPPER_CPU_PCT:g} % core", _verdict(ok)),
        ("gripper relay CPU by thread (% core)", threads, "", "", "", ""),
        (f"gripper state DDS -> agent -> Zenoh, newest sample at {grip['relay_hz']:g} Hz "
         f"(n={lat['n']})", _ms(lat["p50_ms"]), _ms(lat["p99_ms"]), rates, "", ""),
    ]  # fmt: skip


def _stop_row(name: str, stop: dict[str, Any], fan99: float | None, goal: str, ok: bool) -> Row:
    w = stop["last_written"]
    missed = ""
    if stop["incomplete_stops"]:
        missed = (f"; {stop['incomplete_stops']} of {stop['stops']} stops not acked by every arm, "
                  f"fewest answering {stop['fewest_answering']}")  # fmt: skip
    ratio_text = f"{ratio(w['p99_ms'], fan99)} x fan-out p99" if fan99 else ""
    return (f"{name} (n={w['n']}{missed})", _ms(w["p50_ms"]), _ms(w["p99_ms"]), ratio_text, goal,
            _verdict(ok))  # fmt: skip


def _scale_rows(run: dict[str, Any]) -> list[Row]:
    relay, hop, cpu = run["relay"], run["probe_hop"], run["cpu_pct"]
    n, viewer_ok = run["arms"], run["alive"]["viewer"] and cpu["viewer"] <= 50.0
    hop_ratio = f"{ratio(relay['p50_ms'], hop['p50_ms'])} x hop"
    share, flat = _keeps_up(run)
    rates = " / ".join(f"{x:g}" for x in relay["rate_per_arm_hz"])
    stop99 = _stop_p99(run["stop"])
    agents = ", ".join(f"{cpu[f'agent{i}']:g}" for i in range(run["agents"]))
    sims = ", ".join(f"{cpu[f'sim{i}']:g}" for i in range(run["sims"]))
    return [
        (f"{n} arms: raw Zenoh hop alongside (same router, same load)", _ms(hop["p50_ms"]),
         _ms(hop["p99_ms"]), "", "", ""),
        (f"{n} arms, {run['agents']} agents: relay stamp -> client (every 10th arm)",
         _ms(relay["p50_ms"]), _ms(relay["p99_ms"]), hop_ratio, "<= 2 x hop",
         _verdict(relay["p50_ms"] <= 2 * hop["p50_ms"])),
        (f"{n} arms: samples per arm-s at the client, thirds (simulators: "
         f"{run['sim']['per_arm_hz']:g} Hz, nominal {run['nominal_hz']:g})", f"{rates} Hz",
         f"lag x {relay['lag_growth']} (p50 {relay['first_third']['p50_ms']:.2f} -> "
         f"{relay['last_third']['p50_ms']:.2f} ms)", f"{100 * share:.0f} % relayed",
         ">= 95 %, lag <= 1.5 x", _verdict(share >= 0.95 and flat)),
        _stop_row(f"{n} arms: stop -> DDS stop written, last arm", run["stop"], None,
                  "p99 <= 50 ms", stop99 <= 50.0),
        (f"{n} arms: coordinator CPU", f"{cpu['coordinator']:g} % core", "", "", "<= 10 %",
         _verdict(cpu["coordinator"] <= 10.0)),
        (f"{n} arms: viewer CPU (alive at the end: {run['alive']['viewer']})",
         f"{cpu['viewer']:g} % core", "", "", "<= 50 %", _verdict(viewer_ok)),
        (f"{n} arms: agents CPU (% core each)", f"{run['agents_cpu_pct']:g} % core", agents, "", "",
         ""),
        (f"{n} arms: fleet sim CPU (% core each)", f"{run['sims_cpu_pct']:g} % core", sims, "", "",
         ""),
        (f"{n} arms: router; machine busy (of {os.cpu_count()} cores)", f"{cpu['router']:g} % core",
         f"{run['machine_busy_pct']:g} % busy", "", "", ""),
    ]  # fmt: skip


def _routers_rows(run: dict[str, Any]) -> list[Row]:
    relay, hop, fan = run["relay"], run["probe_hop"], run["fanout_100"]
    stop99 = _stop_p99(run["stop"])
    hop_ratio = f"{ratio(relay['p50_ms'], hop['p50_ms'])} x hop"
    return [
        ("two routers: raw Zenoh hop, site -> central (alongside the relay)", _ms(hop["p50_ms"]),
         _ms(hop["p99_ms"]), "", "", ""),
        ("two routers: raw Zenoh fan-out, last of 100 subscribers", _ms(fan["p50_ms"]),
         _ms(fan["p99_ms"]), "", "", ""),
        (f"two routers: relay stamp -> client, {run['arms']} arms, {run['agents']} agents",
         _ms(relay["p50_ms"]), _ms(relay["p99_ms"]), hop_ratio, "<= 1.1 x hop",
         _verdict(relay["p50_ms"] <= 1.1 * hop["p50_ms"])),
        _stop_row(f"two routers: stop -> DDS stop written, last of {run['arms']} arms", run["stop"],
                  fan["p99_ms"], "<= 2 x fan-out p99", stop99 <= 2 * fan["p99_ms"]),
    ]  # fmt: skip


def _issue7_rows(r: dict[str, Any]) -> list[Row]:
    raw, relay, fleet = r["raw"], r["relay"], r["fleet"]
    dds, zen = raw["dds_hop"]["p50_ms"], raw["zenoh_hop"]["p50_ms"]
    hops = dds + zen
    table: list[Row] = [
        _lat_row("raw DDS hop (ArmString_ feedback, 2 processes)", raw["dds_hop"]),
        _lat_row("raw Zenoh hop via router (100 B, 3 processes)", raw["zenoh_hop"]),
    ]
    for n in (10, 50, 100):
        table.append(
            _lat_row(f"raw Zenoh fan-out, last of {n} subscribers", raw[f"zenoh_fanout_{n}"])
        )
    for key, label in (("1x10", "1 arm, 10 Hz"), ("1x100", "1 arm, 100 Hz"),
                       ("10x10", "10 arms, 10 Hz"), ("100x10", "100 arms, 10 Hz")):  # fmt: skip
        lat = relay[key]["latency"]
        goal = "<= 1.1 x hops, p99 <= 3 ms"
        ok: bool | None = lat["p50_ms"] <= 1.1 * hops and lat["p99_ms"] <= 3.0
        if key in ("10x10", "100x10"):
            goal, ok = "(growth)", None
        table.append((f"relay DDS -> agent -> joints, {label}", _ms(lat["p50_ms"]),
                      _ms(lat["p99_ms"]), f"{ratio(lat['p50_ms'], hops)} x hops", goal,
                      _verdict(ok)))  # fmt: skip
    cmd = fleet["command"]
    table.append(("command round trip (query -> DDS -> acks -> reply)", _ms(cmd["p50_ms"]),
                  _ms(cmd["p99_ms"]), f"{ratio(cmd['p50_ms'], 2 * hops)} x 2(DDS+Zenoh)",
                  f"<= {COMMAND_RATIO:g} x",
                  _verdict(cmd["p50_ms"] <= COMMAND_RATIO * 2 * hops)))  # fmt: skip
    for n in (10, 50, 100):
        stop = fleet[f"stop_{n}"]
        fan = raw[f"zenoh_fanout_{n}"]
        w = stop["last_written"]
        verdict = None
        if n == 100:
            verdict = w["p99_ms"] <= STOP_FANOUT_RATIO * fan["p99_ms"] and w["p99_ms"] <= 50.0
        table.append((f"stop -> DDS stop written, last of {n} arms ({stop['agents']} agents)",
                      _ms(w["p50_ms"]), _ms(w["p99_ms"]), f"{ratio(w['p99_ms'], fan['p99_ms'])} x "
                      "fan-out p99",
                      f"<= {STOP_FANOUT_RATIO:g} x, <= 50 ms" if n == 100 else "(growth)",
                      _verdict(verdict)))  # fmt: skip
    for key, arms in (("1x10", 1), ("10x10", 10), ("100x10", 100)):
        run = relay[key]
        ok = {
            1: run["agent_cpu_pct"] <= ONE_ARM_CPU_PCT,
            100: run["agent_cpu_us_per_msg"] <= 60.0,
        }.get(arms)
        goal = {1: f"<= {ONE_ARM_CPU_PCT:g} % core", 100: "<= 60 us/msg"}.get(arms, "(growth)")
        per_msg = f"{run['agent_cpu_us_per_msg']:g} us/msg"
        table.append((f"agent CPU, {arms} arm(s) at 10 Hz", per_msg,
                      f"{run['agent_cpu_pct']:g} % core", "", goal, _verdict(ok)))  # fmt: skip
    for key, arms in (("1x10", 1), ("10x10", 10), ("100x10", 100)):
        run = relay[key]
        rss0, rss1 = run["coordinator_rss_mb"]
        ok = (run["coordinator_cpu_pct"] <= 5.0 and rss1 - rss0 < 1.0) if arms == 100 else None
        table.append((f"coordinator, {arms} arm(s) (CPU; RSS start -> end)",
                      f"{run['coordinator_cpu_pct']:g} % core", f"{rss0:g} -> {rss1:g} MiB", "",
                      "<= 5 %, flat" if arms == 100 else "(growth)", _verdict(ok)))  # fmt: skip
    return table


def markdown(r: dict[str, Any]) -> str:
    """The whole report: header, table, goal list."""
    meta = r["meta"]
    lines = [
        f"## `make bench` ({meta['date']}, {meta['machine']})",
        "",
        f"Wall time {meta['wall_s']:.0f} s; load average {meta['load_start']} at start, "
        f"{meta['load_end']} at end. Latencies: median (p50) and p99 of every sample; "
        "ratios against the raw hops of this run.",
        "",
        "| measure | p50 / value | p99 / other | ratio | goal | result |",
        "|---|---|---|---|---|---|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows(r)]
    lines += ["", "Goals:", ""]
    for g in r["goals"]:
        lines.append(
            f"- {_verdict(g['ok'])}: {g['goal']}: {g['figure']:.2f} {g['unit']} "
            f"(limit {g['limit']:.2f} {g['unit']})"
        )
    return "\n".join(lines) + "\n"
