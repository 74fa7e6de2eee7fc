"""The contact benchmark's family table as markdown (``bench/contact.py``'s output): the rows
it prints as it goes, and ``artifacts/contact/report.md`` written at its end (its header names
the date, the machine, the seed and the load), which ``scripts/docs_results.py`` copies into
``docs/results/contact.md``. Pure but for ``write``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from testkit import runinfo

REPORT = Path(__file__).resolve().parents[1] / "artifacts" / "contact" / "report.md"
HEAD = (
    "| family | calibration | stall recall | grip recall | push recall "
    "| false alarms (per h of free motion) | free-motion force limits | delay p50 / p95 ms |\n"
    "|---|---|---|---|---|---|---|---|"
)


def table_row(family: str, calibration: str, r: dict[str, float]) -> str:
    """One family and configuration's figures (``bench.contact.score``'s) as a table row."""
    return (
        f"| {family} | {calibration} | {r['stall_recall']:.1f}% | {r['grip_recall']:.1f}% | "
        f"{r['push_recall']:.1f}% | {r['false_alarms']:.0f} ({r['fa_per_h']:.1f}) | "
        f"{r['free_force_limits']:.0f} | {r['p50_ms']:.0f} / {r['p95_ms']:.0f} |"
    )


@dataclass(frozen=True)
class ContactRun:
    """Where, when and how a run was made: ``started`` (ISO date), ``machine``
    (``runinfo.machine()``), ``seed``, the episodes per family and configuration (``kinds``:
    how many of each), the detector's default ``methods``, the load average at the start
    and the end, the wall time."""

    started: str
    machine: str
    seed: int
    kinds: dict[str, int]
    methods: tuple[str, ...]
    load_start: tuple[float, float, float]
    load_end: tuple[float, float, float]
    wall_s: float


def markdown(run: ContactRun, rows: list[str]) -> str:
    """The report: a header naming the run, then the table of ``rows`` (``table_row``'s)."""
    kinds = ", ".join(f"{n} {kind}" for kind, n in run.kinds.items())
    return "\n".join(
        [
            f"`python -m bench --only contact` ({run.started[:16].replace('T', ' ')}, "
            f"{run.machine}; seed {run.seed}): {sum(run.kinds.values())} episodes per family "
            f"and configuration ({kinds}); the default combination "
            f"{'+'.join(run.methods)}. Wall time {run.wall_s:.0f} s, load average "
            f"{_load(run.load_start)} at the start, {_load(run.load_end)} at the end (the "
            "figures are simulated time and do not depend on the load).",
            "",
            HEAD,
            *rows,
        ]
    )


def write(text: str, path: Path = REPORT) -> Path:
    """Write the report (with its folder); its path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n", encoding="utf-8")
    return path


def now(seed: int, kinds: dict[str, int], methods: tuple[str, ...]) -> ContactRun:
    """A run starting now on this machine (its end filled in by ``finished``)."""
    load = runinfo.load()
    return ContactRun(runinfo.now_iso(), runinfo.machine(), seed, kinds, methods, load, load, 0.0)


def finished(run: ContactRun, wall_s: float) -> ContactRun:
    """``run`` with its end: the load average now and the wall time."""
    return dataclasses.replace(run, load_end=runinfo.load(), wall_s=wall_s)


def _load(load: tuple[float, float, float]) -> str:
    return " ".join(f"{value:.1f}" for value in load)
