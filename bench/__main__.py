"""``python -m bench`` (``make bench``): run every section, print the table, save JSON and
Markdown. Order: raw hops, fan-outs, relay and cost, command and stop, viewer, contact, 1000
arms, two routers, raw hops again (the raw figures pool both repetitions, so drift in the
machine's load over the run shows). ``--only SECTION`` (repeatable) runs some of them."""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import (
    contact,
    devices,
    fleet_runs,
    one_core,
    raw,
    relay,
    report,
    ros2,
    scale,
    viewer_cpu,
)
from bench.proc import REPO
from testkit import runinfo


def _load() -> str:
    return " ".join(f"{value:.2f}" for value in runinfo.load())


def _strip_samples(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _strip_samples(v) for k, v in value.items() if k != "samples_ns"}
    if isinstance(value, list):
        return [_strip_samples(v) for v in value]
    return value


SECTIONS = (
    "raw", "relay", "fleet", "viewer", "contact", "devices", "onecore", "ros2", "scale",
    "routers",
)  # fmt: skip
"""raw: hops and fan-outs; relay: latency and cost at 1-100 arms; fleet: command and stop;
devices: one Dex1-1 at 500 Hz; onecore: one agent for a D1 and its Dex1-1 vs two
processes, a device's stop under a flood; scale: 1000 arms; routers: two routers."""


_STEPS: tuple[tuple[str, str, Callable[[bool], Any]], ...] = (
    ("relay", "relay latency and cost at 1, 10, 100 arms (with the coordinator)", relay.run),
    ("fleet", "command round trip; stop fan-out to 10, 50, 100 arms", fleet_runs.run),
    ("viewer", "viewer CPU at 10, 50, 200 arms; 50 arms and a G1", viewer_cpu.run),
    ("contact", "contact detection: labelled episodes (pure simulator + detector)",
     lambda _quick: contact.bench_contact()),
    ("devices", "one Dex1-1 at 500 Hz: devices agent CPU, latency DDS -> Zenoh", devices.run),
    ("onecore", "D1 + Dex1-1: one agent vs two; a device's stop under a flood", one_core.run),
    ("ros2", "fleet ros2: joint_states latency over the joints key, CPU at 10 arms", ros2.run),
    ("scale", "1000 arms at 10 Hz: 4 fleet sim, 4 agents, coordinator, viewer; stops",
     scale.run_thousand),
    ("routers", "two routers: raw hop and fan-out over them; relay and stops of 100 arms",
     scale.run_two_routers),
)  # fmt: skip
"""The sections after the raw hops, in order: (name, what it measures, function of quick)."""


def run(quick: bool, sections: tuple[str, ...] = SECTIONS) -> dict[str, Any]:
    """The ``sections`` (every one by default); returns the results with their goals."""
    started = time.monotonic()
    meta: dict[str, Any] = {
        "date": runinfo.now_iso(),
        "machine": runinfo.machine(),
        "load_start": _load(),
        "quick": quick,
    }

    def step(name: str) -> None:
        print(f"[bench {time.monotonic() - started:5.0f} s] {name}", flush=True)

    results: dict[str, Any] = {"meta": meta}
    if "raw" in sections:
        step("raw DDS and Zenoh hops")
        first = raw.hops(quick)
        step("raw Zenoh fan-out to 10, 50, 100 subscribers")
        results["raw"] = raw.fanouts(quick)
    for name, what, measure in _STEPS:
        if name in sections:
            step(what)
            results[name] = measure(quick)
    if "raw" in sections:
        step("raw DDS and Zenoh hops again")
        second = raw.hops(quick)
        for key in ("dds_hop", "zenoh_hop"):
            results["raw"][key] = raw.pooled(first[key], second[key])
    meta["load_end"] = _load()
    meta["wall_s"] = round(time.monotonic() - started, 1)
    meta["sections"] = list(sections)
    results = _strip_samples(results)
    results["goals"] = report.goals(results)
    return results


def main(argv: list[str] | None = None) -> int:
    """Run, print the table, write bench-results.json and bench/latest.md."""
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="short windows (a smoke run)")
    parser.add_argument("--no-viewer", action="store_true", help="skip the viewer's CPU")
    parser.add_argument(
        "--only", action="append", choices=SECTIONS, help="run this section only (repeatable)"
    )
    parser.add_argument("--json", default=str(REPO / "bench-results.json"))
    parser.add_argument("--markdown", default=str(REPO / "bench" / "latest.md"))
    args = parser.parse_args(argv)
    sections = tuple(args.only or SECTIONS)
    if args.no_viewer:
        sections = tuple(s for s in sections if s != "viewer")
    results = run(args.quick, sections)
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
