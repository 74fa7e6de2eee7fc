"""The soak's record and its report: per-process memory and CPU, stop times, events, goals.

Definitions (also printed in the report):
- **warm-up**: the first ``WARMUP_SHARE`` (20 %) of the run: imports, first connections,
  caches and allocator pools fill up then;
- **RSS after warm-up** / **RSS at the end**: the median of the samples in the window of
  ``window`` seconds (10 % of the run, 15 s to 2 min) that starts when warm-up ends / that ends
  the run (a median, so one sample taken mid-allocation does not decide);
- **growth**: end over after-warm-up, in percent; the goal is < ``GROWTH_LIMIT_PCT`` for every
  process that ran the whole soak (a restarted agent starts over, so its growth is not judged;
  its row gives the RSS at the end of each of its runs instead);
- **CPU**: percent of one core between two samples, mean and max after warm-up;
- **stop times** (from the stop's ``stamp_ns``, last arm): every arm's DDS stop written
  (``dds_written_ns``), every arm seen still (``still_ns``), and the ``estop`` call until it
  returned with every ack; **arms moving**: some joint moved more than 0.5 deg in the 0.3 s
  before the stop (the dance was on); a stop is **confirmed** when every arm acknowledged it with
  ``still_ns`` and the soak's own joints samples moved at most 0.5 deg over 0.5 s after it.
"""

from __future__ import annotations

import json
import statistics
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from bench.stats import percentile
from fleet.wire.messages import StopAck

WARMUP_SHARE = 0.2
GROWTH_LIMIT_PCT = 5.0


@dataclass
class SoakRecord:
    """Everything a soak measured; ``soak.json`` is this, as JSON."""

    duration_s: float
    period_s: float
    load_start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_end: tuple[float, float, float] = (0.0, 0.0, 0.0)
    samples: dict[str, list[tuple[int, float, float, float | None]]] = field(default_factory=dict)
    """role -> (incarnation, t_s, rss_mib, cpu_percent or None for a first sample)."""
    stops: list[dict[str, Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    died: list[tuple[float, str, int | None]] = field(default_factory=list)
    diag: list[tuple[float, dict[str, dict[str, float]]]] = field(default_factory=list)
    load: list[tuple[float, float]] = field(default_factory=list)

    def add_sample(
        self, role: str, incarnation: int, t: float, rss: float, cpu: float | None
    ) -> None:
        """One /proc sample of one process."""
        cpu_pct = None if cpu is None else round(cpu, 2)
        self.samples.setdefault(role, []).append((incarnation, round(t, 2), round(rss, 2), cpu_pct))

    def add_stop(
        self,
        t: float,
        stamp_ns: int,
        acks: dict[str, StopAck | None],
        call_ms: float,
        confirmed: bool,
    ) -> None:
        """One fleet stop: the last arm's times from the stop's stamp, in ms."""

        def last(attr: str) -> float | None:
            values = [getattr(a, attr) for a in acks.values() if a is not None]
            if not values or any(v is None for v in values) or len(values) < len(acks):
                return None
            return round((max(values) - stamp_ns) / 1e6, 3)

        self.stops.append(
            {
                "t": round(t, 1),
                "received_ms": last("received_ns"),
                "written_ms": last("dds_written_ns"),
                "still_ms": last("still_ns"),
                "call_ms": round(call_ms, 1),
                "confirmed": confirmed,
            }
        )


@dataclass
class ProcessRow:
    """One process's line of the report."""

    role: str
    incarnations: int
    rss_start: float
    rss_warm: float | None
    rss_end: float
    growth_pct: float | None
    cpu_mean: float
    cpu_max: float
    judged: bool
    run_ends: tuple[float, float] | None = None
    """A restarted process: the smallest and largest RSS at the end of one of its runs."""

    @property
    def passed(self) -> bool:
        """Growth under the limit (or not judged: restarted)."""
        return not self.judged or (
            self.growth_pct is not None and self.growth_pct < GROWTH_LIMIT_PCT
        )


def _window(duration_s: float) -> float:
    return min(120.0, max(15.0, 0.1 * duration_s))


def process_rows(record: SoakRecord, incarnations: dict[str, int]) -> list[ProcessRow]:
    """Memory and CPU per process. A restarted process has no "after warm-up" of its own
    (its last run may be a minute old): its row gives the RSS at the end of each run instead."""
    warm = WARMUP_SHARE * record.duration_s
    window = _window(record.duration_s)
    rows = []
    for role, samples in record.samples.items():
        n = incarnations.get(role, 1)
        mine = [s for s in samples if s[0] == n]
        if not mine:
            continue
        end_t = mine[-1][1]
        tail = [s[2] for s in mine if s[1] >= end_t - window]
        rss_end = statistics.median(tail)
        cpus = [s[3] for s in samples if s[3] is not None and s[1] >= warm]
        rss_warm = growth = None
        run_ends = None
        if n == 1:
            after = [s[2] for s in mine if warm <= s[1] < warm + window] or [mine[0][2]]
            rss_warm = statistics.median(after)
            growth = round(100.0 * (rss_end - rss_warm) / rss_warm, 2) if rss_warm else None
        else:
            last: dict[int, float] = {}
            for s in samples:
                last[s[0]] = s[2]  # samples are in time order: the last one of each run wins
            ends = list(last.values())
            run_ends = (min(ends), max(ends))
        rows.append(
            ProcessRow(
                role=role,
                incarnations=n,
                rss_start=mine[0][2] if n == 1 else samples[0][2],
                rss_warm=rss_warm,
                rss_end=rss_end,
                growth_pct=growth,
                cpu_mean=round(statistics.fmean(cpus), 2) if cpus else 0.0,
                cpu_max=round(max(cpus), 1) if cpus else 0.0,
                judged=n == 1,
                run_ends=run_ends,
            )
        )
    return rows


def _stats(values: list[float]) -> str:
    if not values:
        return "n/a"
    ordered = sorted(values)
    p50, p99 = percentile(ordered, 50), percentile(ordered, 99)
    return f"{p50:.1f} / {p99:.1f} / {ordered[-1]:.1f}"


def markdown(record: SoakRecord, rows: list[ProcessRow]) -> tuple[str, bool]:
    """The report as Markdown, and whether every goal was met."""
    stops = record.stops
    confirmed = sum(1 for s in stops if s["confirmed"])
    moving = sum(1 for s in stops if (s.get("moving_deg") or 0.0) > 0.5)
    failed_events = [e for e in record.events if not e["ok"]]
    loads = [v for _t, v in record.load]
    lines = [
        f"Duration {record.duration_s / 60:.1f} min, an event every {record.period_s:.0f} s; "
        f"warm-up {WARMUP_SHARE * record.duration_s:.0f} s, RSS windows "
        f"{_window(record.duration_s):.0f} s. Load average (1 min) "
        f"{record.load_start[0]:.2f} at start, {record.load_end[0]:.2f} at end, "
        f"mean {statistics.fmean(loads) if loads else 0:.2f}, max {max(loads, default=0):.2f} "
        "(2 cores, shared).",
        "",
        "| process | runs | RSS start MiB | after warm-up | end | growth | CPU % core mean / max "
        "| memory goal |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        growth = "n/a" if r.growth_pct is None else f"{r.growth_pct:+.2f} %"
        warm = "n/a" if r.rss_warm is None else f"{r.rss_warm:.1f}"
        verdict = ("PASS" if r.passed else "**FAIL**") if r.judged else "n/a (restarted)"
        if r.run_ends is not None:
            verdict += f"; RSS at the end of each run {r.run_ends[0]:.1f}-{r.run_ends[1]:.1f}"
        lines.append(
            f"| {r.role} | {r.incarnations} | {r.rss_start:.1f} | {warm} | "
            f"{r.rss_end:.1f} | {growth} | {r.cpu_mean:.1f} / {r.cpu_max:.1f} | {verdict} |"
        )
    lines += [
        "",
        "| stops | confirmed | arms moving at the stop | DDS written, last arm (ms) p50 / p99 / "
        "max | all still (ms) | estop call (ms) |",
        "|---:|---:|---:|---|---|---|",
        f"| {len(stops)} | {confirmed} | {moving} | "
        f"{_stats([s['written_ms'] for s in stops if s['written_ms'] is not None])} | "
        f"{_stats([s['still_ms'] for s in stops if s['still_ms'] is not None])} | "
        f"{_stats([s['call_ms'] for s in stops])} |",
        "",
        "| event | count | failed |",
        "|---|---:|---:|",
    ]
    kinds: dict[str, list[bool]] = {}
    for e in record.events:
        kinds.setdefault(e["kind"], []).append(e["ok"])
    for kind, oks in kinds.items():
        lines.append(f"| {kind} | {len(oks)} | {oks.count(False)} |")
    lines += ["", _diag_line(record)]
    goals = [
        (
            f"memory growth after warm-up < {GROWTH_LIMIT_PCT:g} % for every process that ran "
            "throughout",
            all(r.passed for r in rows) and any(r.judged for r in rows),
        ),
        (
            f"every stop confirmed ({confirmed} of {len(stops)})",
            bool(stops) and confirmed == len(stops),
        ),
        (f"every event succeeded ({len(failed_events)} failed)", not failed_events),
        (f"no process died ({len(record.died)})", not record.died),
    ]
    lines += ["", "Goals:", ""]
    lines += [f"- {'PASS' if ok else '**FAIL**'}: {text}" for text, ok in goals]
    for e in failed_events:
        lines.append(f"  - failed at {e['t']} s: {e['kind']} {e['target']}: {e['detail']}")
    for t, role, code in record.died:
        lines.append(f"  - {role} exited with {code} at {t} s (restarted)")
    return "\n".join(lines) + "\n", all(ok for _text, ok in goals)


def _diag_line(record: SoakRecord) -> str:
    """The diag counters at the end (queue overflows, busy answers), and the coordinator's
    largest number of requests in flight."""
    if not record.diag:
        return "No diag received."
    final = record.diag[-1][1]
    active = max(
        (d.get("coordinator", {}).get("requests_active", 0) for _t, d in record.diag), default=0
    )
    parts = []
    for name in sorted(final):
        counters = final[name]
        picked = ("busy", "dropped_events", "bad_payloads", "write_failures", "ack_timeouts")
        shown = ", ".join(f"{k} {int(counters[k])}" for k in picked if k in counters)
        parts.append(f"{name}: {shown}")
    return (
        "Diag counters at the end (per agent since its last start): "
        + "; ".join(parts)
        + f"; coordinator requests in flight, max sampled: {int(active)}."
    )


def plot(record: SoakRecord, path: Path) -> str | None:
    """``soak.png``: RSS and CPU per process over time, stop times; None when drawn, else why
    not (matplotlib is the optional ``soak`` extra)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "no plot: matplotlib is missing (pip install -e '.[soak]')"
    fig, (ax_rss, ax_rel, ax_cpu, ax_stop) = plt.subplots(4, 1, figsize=(11, 12), sharex=True)
    warm = WARMUP_SHARE * record.duration_s
    window = _window(record.duration_s)
    colors = plt.get_cmap("tab10").colors
    for index, (role, samples) in enumerate(sorted(record.samples.items())):
        color = colors[index % len(colors)]
        for n in sorted({s[0] for s in samples}):
            mine = [s for s in samples if s[0] == n]
            label = role if n == 1 else None
            times = [s[1] for s in mine]
            ax_rss.plot(times, [s[2] for s in mine], label=label, color=color)
            base = [s[2] for s in mine if warm <= s[1] < warm + window]
            if n == 1 and base:
                ref = statistics.median(base)
                ax_rel.plot(times, [100.0 * (s[2] - ref) / ref for s in mine], color=color)
            cpu = [(s[1], s[3]) for s in mine if s[3] is not None]
            ax_cpu.plot([c[0] for c in cpu], [c[1] for c in cpu], color=color, lw=0.7)
    for ax in (ax_rss, ax_rel, ax_cpu, ax_stop):
        ax.axvspan(0, warm, color="0.92", zorder=0)
    ax_rss.set_ylabel("RSS (MiB)")
    ax_rss.legend(fontsize=7, ncol=4, loc="upper left")
    ax_rss.set_title("d1-fleet soak (grey: warm-up)")
    for limit in (GROWTH_LIMIT_PCT, -GROWTH_LIMIT_PCT):
        ax_rel.axhline(limit, color="red", lw=0.8, ls="--")
    ax_rel.set_ylabel("RSS vs after warm-up (%)\n(processes never restarted)")
    ax_cpu.set_ylabel("CPU (% of a core)")
    for key, marker in (("written_ms", "o"), ("still_ms", "^")):
        points = [(s["t"], s[key]) for s in record.stops if s[key] is not None]
        ax_stop.plot([p[0] for p in points], [p[1] for p in points], marker, label=key)
    bad = [s["t"] for s in record.stops if not s["confirmed"]]
    for t in bad:
        ax_stop.axvline(t, color="red", lw=1)
    ax_stop.set_yscale("log")
    ax_stop.set_ylabel("stop: last arm (ms)")
    ax_stop.set_xlabel("time since start (s)")
    ax_stop.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return None


def load_record(path: Path) -> tuple[SoakRecord, dict[str, int]]:
    """A record from ``soak.json``, and the runs of each process."""
    data = json.loads(path.read_text(encoding="utf-8"))
    record = SoakRecord(**data)
    runs = {role: max(s[0] for s in samples) for role, samples in record.samples.items()}
    return record, runs


def _load_for_cli(directory: Path) -> tuple[SoakRecord, Path, dict[str, int]]:
    record, runs = load_record(directory / "soak.json")
    return record, directory, runs


def write_report(record: SoakRecord, out: Path, incarnations: dict[str, int]) -> bool:
    """Write ``report.md``, ``soak.png`` and ``soak.json`` into ``out``, print the report;
    True when every goal was met."""
    rows = process_rows(record, incarnations)
    text, passed = markdown(record, rows)
    why_no_plot = plot(record, out / "soak.png")
    if why_no_plot:
        text += f"\n{why_no_plot}\n"
    (out / "report.md").write_text(text, encoding="utf-8")
    (out / "soak.json").write_text(json.dumps(asdict(record)), encoding="utf-8")
    print(f"\n{text}\nwritten: {out / 'report.md'}, {out / 'soak.png'}, {out / 'soak.json'}")
    return passed


if __name__ == "__main__":  # python -m bench.soak_report artifacts/soak: the report again
    import sys

    directory = Path(sys.argv[1] if len(sys.argv) > 1 else "artifacts/soak")
    sys.exit(0 if write_report(*_load_for_cli(directory)) else 1)
