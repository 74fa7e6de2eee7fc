"""The network lab's fault-matrix rows as records, and the table rendered from them.

Each lab test that is a row of the fault matrix (``tests/netlab``) appends one ``RowRecord``
per run of it (its row, test, case and kind, the bound, what it measured, its figures and
pytest's verdict, with the run's date, host, CPU and load average) to ``ROWS``, one JSON
line each; ``render`` turns the newest record of each row, test, case and kind into the
markdown table of ``REPORT``, which ``scripts/docs_results.py`` copies into
``docs/results/fault-matrix.md``. Pure but for ``append``, ``read`` and ``write_report``.

``python -m testkit.labrows [ROWS] [REPORT]`` renders again (delete ``ROWS`` to start afresh:
a test renamed or removed keeps its last record until then).
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import msgspec

ROOT = Path(__file__).resolve().parents[1]
ROWS = ROOT / "artifacts" / "netlab" / "rows.jsonl"
REPORT = ROOT / "artifacts" / "netlab" / "report.md"
FAILURE_CHARS = 300
"""A failure's message is cut to this in the table (its first line; the log has the rest)."""


class RowRecord(msgspec.Struct, frozen=True, kw_only=True):
    """One run of one fault-matrix row for one kind.

    ``run``: when the pytest session started (its records share it); ``date``: when this
    test ended; ``cpu``: ``N x model``; ``load``: the load average (1, 5, 15 min) at its end;
    ``test``: ``file::function``; ``case``: its parameters other than the kind (``loss10``,
    ``kill``; empty without); ``verdict``: ``passed``, ``xfail: why``, ``failed: why``."""

    run: str
    date: str
    host: str
    cpu: str
    load: tuple[float, float, float]
    row: str
    test: str
    case: str
    kind: str
    bound: str
    measured: str
    verdict: str
    figures: dict[str, Any] = {}

    @property
    def key(self) -> tuple[str, str, str, str]:
        """What a newer record replaces: the same row, test, case and kind."""
        return self.row, self.test, self.case, self.kind


_decoder = msgspec.json.Decoder(RowRecord)


def append(record: RowRecord, path: Path = ROWS) -> None:
    """Add ``record`` as one JSON line at the end of ``path`` (created with its folder)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("ab") as out:
        out.write(msgspec.json.encode(record) + b"\n")


def parse(lines: Iterable[str]) -> tuple[list[RowRecord], int]:
    """The records of ``lines`` in their order, and how many lines were not one (a run killed
    mid-write leaves half a line: counted, skipped)."""
    records, bad = [], 0
    for line in lines:
        if not line.strip():
            continue
        try:
            records.append(_decoder.decode(line))
        except (msgspec.DecodeError, msgspec.ValidationError):
            bad += 1
    return records, bad


def read(path: Path = ROWS) -> tuple[list[RowRecord], int]:
    """``parse`` of the file at ``path`` (nothing when it does not exist)."""
    if not path.is_file():
        return [], 0
    return parse(path.read_text(encoding="utf-8").splitlines())


def newest(records: list[RowRecord]) -> list[RowRecord]:
    """The last record of each key, ordered by row, then by where its test, kind and case
    first appear (the lab's run order: a row's kinds together, each kind's cases in order)."""
    last: dict[tuple[str, str, str, str], RowRecord] = {}
    first: dict[tuple[str, str], int] = {}
    for record in records:
        last[record.key] = record
        for part in (("test", record.test), ("kind", record.kind), ("case", record.case)):
            first.setdefault(part, len(first))

    def order(record: RowRecord) -> tuple[Any, ...]:
        row = (0, int(record.row), "") if record.row.isdigit() else (1, 0, record.row)
        kind, case = first[("kind", record.kind)], first[("case", record.case)]
        return (*row, first[("test", record.test)], kind, case)

    return sorted(last.values(), key=order)


def render(records: list[RowRecord], unreadable: int = 0) -> str:
    """The markdown of the newest records: which runs they come from, then the table."""
    shown = newest(records)
    if not shown:
        return "No lab rows recorded yet: run `.venv/bin/python -m pytest tests/netlab`."
    lines = [_runs_line(shown, unreadable), ""]
    lines.append("| row | test | kind | bound | measured | verdict | ended (load) |")
    lines.append("|---|---|---|---|---|---|---|")
    for r in shown:
        test = f"`{r.test.split('::')[0]}` `{r.test.split('::')[-1]}`"
        if r.case:
            test += f" `[{r.case}]`"
        ended = f"{r.date[:16].replace('T', ' ')} ({r.load[0]:.1f})"
        cells = (r.row, test, r.kind, r.bound, r.measured, verdict_text(r.verdict), ended)
        lines.append("| " + " | ".join(cell(c) for c in cells) + " |")
    return "\n".join(lines)


def verdict_text(verdict: str) -> str:
    """``passed`` as **pass**, an xfail's reason in full, a failure's first line, cut."""
    outcome, _, why = verdict.partition(": ")
    if outcome == "passed":
        return "**pass**"
    if outcome == "xfail":
        return f"XFAIL: {why}"
    first = why.splitlines()[0] if why else ""
    if len(first) > FAILURE_CHARS:
        first = first[: FAILURE_CHARS - 3] + "..."
    return f"**{outcome.upper()}**: {first}" if first else f"**{outcome.upper()}**"


def cell(text: str) -> str:
    """``text`` as one markdown table cell: on one line, its pipes escaped."""
    return " ".join(text.split()).replace("|", "\\|")


def _runs_line(shown: list[RowRecord], unreadable: int) -> str:
    """Where and when the shown records were measured, one clause per run."""
    runs: dict[str, list[RowRecord]] = {}
    for record in shown:
        runs.setdefault(record.run, []).append(record)
    parts = []
    for run, rows in sorted(runs.items()):
        loads = [r.load[0] for r in rows]
        first = rows[0]
        parts.append(
            f"{run[:16].replace('T', ' ')} on `{first.host}` ({first.cpu}): {len(rows)} "
            f"row{'s' if len(rows) > 1 else ''}, load average {min(loads):.1f}-"
            f"{max(loads):.1f} at their ends"
        )
    skipped = f" ({unreadable} unreadable lines skipped)" if unreadable else ""
    return (
        "The newest record of each row, test and kind in `artifacts/netlab/rows.jsonl`"
        f"{skipped}, from the run{'s' if len(runs) > 1 else ''} of " + "; ".join(parts) + "."
    )


def write_report(rows: Path = ROWS, report: Path = REPORT) -> str:
    """Render ``rows`` into ``report``; the text written."""
    records, unreadable = read(rows)
    text = render(records, unreadable) + "\n"
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text(text, encoding="utf-8")
    return text


def main(argv: list[str] | None = None) -> int:
    """``python -m testkit.labrows [ROWS] [REPORT]``."""
    args = sys.argv[1:] if argv is None else argv
    rows = Path(args[0]) if args else ROWS
    report = Path(args[1]) if len(args) > 1 else REPORT
    write_report(rows, report)
    print(f"{report}: rendered from {rows}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
