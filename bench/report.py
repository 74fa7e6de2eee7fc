"""The benchmark's table: every figure with its goal from issue 7 and PASS/FAIL, as Markdown.

Latency goals are ratios against the raw hops measured in the same run; a goal is never
loosened here: a missed goal prints FAIL with the figure.
"""

from __future__ import annotations

import math
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


def goals(r: dict[str, Any]) -> list[dict[str, Any]]:
    """Each goal of issue 7 with its figure, limit and verdict (also saved in the JSON)."""
    raw, relay, fleet = r["raw"], r["relay"], r["fleet"]
    dds, zen = raw["dds_hop"]["p50_ms"], raw["zenoh_hop"]["p50_ms"]
    hops = dds + zen
    out: list[dict[str, Any]] = []

    def add(name: str, figure: float, limit: float, unit: str) -> None:
        ok = None if math.isnan(figure) or math.isnan(limit) else figure <= limit
        out.append({"goal": name, "figure": figure, "limit": limit, "unit": unit, "ok": ok})

    for rate in ("10", "100"):
        lat = relay[f"1x{rate}"]["latency"]
        add(f"relay p50 at {rate} Hz <= 1.1 x (DDS + Zenoh hop)", lat["p50_ms"], 1.1 * hops, "ms")
    add("relay p99 at 100 Hz <= 3 ms", relay["1x100"]["latency"]["p99_ms"], 3.0, "ms")
    add(
        "command p50 <= 1.25 x (2 DDS + 2 Zenoh hops)", fleet["command"]["p50_ms"], 2.5 * hops, "ms"
    )
    stop99 = fleet["stop_100"]["last_written"]["p99_ms"]
    fan99 = raw["zenoh_fanout_100"]["p99_ms"]
    add("stop to last of 100 arms p99 <= 2 x raw fan-out p99", stop99, 2 * fan99, "ms")
    add("stop to last of 100 arms p99 <= 50 ms", stop99, 50.0, "ms")
    big = relay["100x10"]
    add("agent CPU per relayed message (100 arms, 10 Hz)", big["agent_cpu_us_per_msg"], 60.0, "us")
    add("agent CPU, 100 arms at 10 Hz (% of a core)", big["agent_cpu_pct"], 6.0, "%")
    add("coordinator CPU with 100 arms (% of a core)", big["coordinator_cpu_pct"], 5.0, "%")
    rss0, rss1 = big["coordinator_rss_mb"]
    add(
        f"coordinator RSS growth over {big['window_s']:g} s (flat: < 1 MiB)",
        rss1 - rss0,
        1.0,
        "MiB",
    )
    viewer50 = r.get("viewer", {}).get("50", math.nan)
    add("viewer CPU, 50 arms at 10 Hz (% of a core)", viewer50, 15.0, "%")
    contact = r.get("contact", {}).get("default")
    if contact:
        add("contact: stalls missed (recall >= 99 %)", 100.0 - contact["stall_recall"], 1.0, "%")
        add("contact: false alarms in free motion", contact["false_alarms"], 0.0, "")
        add("contact: detection delay p95 <= 300 ms", contact["p95_ms"], 300.0, "ms")
    return out


def rows(r: dict[str, Any]) -> list[Row]:
    """The table's rows."""
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
        goal = "<= 1.1 x hops" + (", p99 <= 3 ms" if key == "1x100" else "")
        ok: bool | None = lat["p50_ms"] <= 1.1 * hops
        if key == "1x100":
            ok = ok and lat["p99_ms"] <= 3.0
        if key in ("10x10", "100x10"):
            goal, ok = "(growth)", None
        table.append((f"relay DDS -> agent -> joints, {label}", _ms(lat["p50_ms"]),
                      _ms(lat["p99_ms"]), f"{ratio(lat['p50_ms'], hops)} x hops", goal,
                      _verdict(ok)))  # fmt: skip
    cmd = fleet["command"]
    table.append(("command round trip (query -> DDS -> acks -> reply)", _ms(cmd["p50_ms"]),
                  _ms(cmd["p99_ms"]), f"{ratio(cmd['p50_ms'], 2 * hops)} x 2(DDS+Zenoh)",
                  "<= 1.25 x", _verdict(cmd["p50_ms"] <= 2.5 * hops)))  # fmt: skip
    for n in (10, 50, 100):
        stop = fleet[f"stop_{n}"]
        fan = raw[f"zenoh_fanout_{n}"]
        w = stop["last_written"]
        verdict = None
        if n == 100:
            verdict = w["p99_ms"] <= 2 * fan["p99_ms"] and w["p99_ms"] <= 50.0
        table.append((f"stop -> DDS stop written, last of {n} arms ({stop['agents']} agents)",
                      _ms(w["p50_ms"]), _ms(w["p99_ms"]), f"{ratio(w['p99_ms'], fan['p99_ms'])} x "
                      "fan-out p99", "<= 2 x, <= 50 ms" if n == 100 else "(growth)",
                      _verdict(verdict)))  # fmt: skip
    for key, arms in (("1x10", 1), ("10x10", 10), ("100x10", 100)):
        run = relay[key]
        ok = run["agent_cpu_us_per_msg"] <= 60.0 if arms == 100 else None
        per_msg = f"{run['agent_cpu_us_per_msg']:g} us/msg"
        table.append((f"agent CPU, {arms} arm(s) at 10 Hz", per_msg,
                      f"{run['agent_cpu_pct']:g} % core", "", "<= 60 us/msg" if arms == 100
                      else "(growth)", _verdict(ok)))  # fmt: skip
    for key, arms in (("1x10", 1), ("10x10", 10), ("100x10", 100)):
        run = relay[key]
        rss0, rss1 = run["coordinator_rss_mb"]
        ok = (run["coordinator_cpu_pct"] <= 5.0 and rss1 - rss0 < 1.0) if arms == 100 else None
        table.append((f"coordinator, {arms} arm(s) (CPU; RSS start -> end)",
                      f"{run['coordinator_cpu_pct']:g} % core", f"{rss0:g} -> {rss1:g} MiB", "",
                      "<= 5 %, flat" if arms == 100 else "(growth)", _verdict(ok)))  # fmt: skip
    for arms, pct in r.get("viewer", {}).items():
        ok = pct <= 15.0 if arms == "50" else None
        table.append((f"viewer CPU, {arms} arms at 10 Hz", f"{pct:g} % core", "", "",
                      "<= 15 %" if arms == "50" else "(growth)", _verdict(ok)))  # fmt: skip
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
    lines += ["", "Goals of issue 7:", ""]
    for g in r["goals"]:
        lines.append(
            f"- {_verdict(g['ok'])}: {g['goal']}: {g['figure']:.2f} {g['unit']} "
            f"(limit {g['limit']:.2f} {g['unit']})"
        )
    return "\n".join(lines) + "\n"
