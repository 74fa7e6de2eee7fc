"""``python -m bench`` (``make bench``): run every section, print the table, save JSON and
Markdown. Order: raw hops, fan-outs, relay and cost, command and stop, viewer, raw hops again
(the raw figures pool both repetitions, so drift in the machine's load over the run shows)."""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

from bench import contact, fleet_runs, raw, relay, report, viewer_cpu
from bench.proc import REPO


def _machine() -> str:
    model = "unknown CPU"
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            model = line.split(":", 1)[1].strip()
            break
    return f"{platform.node()}, {os.cpu_count()} x {model}, Python {platform.python_version()}"


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def _strip_samples(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _strip_samples(v) for k, v in value.items() if k != "samples_ns"}
    if isinstance(value, list):
        return [_strip_samples(v) for v in value]
    return value


def run(quick: bool, viewer: bool) -> dict[str, Any]:
    """Every section; returns the results with their goals."""
    started = time.monotonic()
    meta: dict[str, Any] = {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "machine": _machine(),
        "load_start": _load(),
        "quick": quick,
    }

    def step(name: str) -> None:
        print(f"[bench {time.monotonic() - started:5.0f} s] {name}", flush=True)

    step("raw DDS and Zenoh hops")
    first = raw.hops(quick)
    step("raw Zenoh fan-out to 10, 50, 100 subscribers")
    raw_results = raw.fanouts(quick)
    step("relay latency and cost at 1, 10, 100 arms (with the coordinator)")
    relay_results = relay.run(quick)
    step("command round trip; stop fan-out to 10, 50, 100 arms")
    fleet_results = fleet_runs.run(quick)
    viewer_results: dict[str, Any] = {}
    if viewer:
        step("viewer CPU at 10, 50, 200 arms")
        viewer_results = viewer_cpu.run(quick)
    step("contact detection: labelled episodes (pure simulator + detector)")
    contact_results = contact.bench_contact()
    step("raw DDS and Zenoh hops again")
    second = raw.hops(quick)
    for key in ("dds_hop", "zenoh_hop"):
        raw_results[key] = raw.pooled(first[key], second[key])
    meta["load_end"] = _load()
    meta["wall_s"] = round(time.monotonic() - started, 1)
    results = {
        "meta": meta,
        "raw": raw_results,
        "relay": relay_results,
        "fleet": fleet_results,
        "viewer": viewer_results,
        "contact": contact_results,
    }
    results = _strip_samples(results)
    results["goals"] = report.goals(results)
    return results


def main(argv: list[str] | None = None) -> int:
    """Run, print the table, write bench-results.json and bench/latest.md."""
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="short windows (a smoke run)")
    parser.add_argument("--no-viewer", action="store_true", help="skip the viewer's CPU")
    parser.add_argument("--json", default=str(REPO / "bench-results.json"))
    parser.add_argument("--markdown", default=str(REPO / "bench" / "latest.md"))
    args = parser.parse_args(argv)
    results = run(args.quick, not args.no_viewer)
    text = report.markdown(results)
    notes = REPO / "bench" / "NOTES.md"
    if notes.exists():
        text += "\n" + notes.read_text(encoding="utf-8")
    print(text, flush=True)
    Path(args.json).write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    Path(args.markdown).write_text(text, encoding="utf-8")
    print(f"saved {args.json} and {args.markdown}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
