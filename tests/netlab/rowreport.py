"""The fault-matrix record of a lab test: ``RowReport`` (the ``row_report`` fixture) prints
what the test measured and keeps it with its bound and figures; ``record`` (called by the
package's ``pytest_runtest_makereport``) adds pytest's verdict and the run's date, host, CPU and
load average, appends it to ``artifacts/netlab/rows.jsonl`` and renders the report again
(``testkit.labrows``). A module is a row of the fault matrix when it names it: ``ROW = "1"``."""

from __future__ import annotations

from typing import Any

import pytest

from testkit import labrows, runinfo

RUN = runinfo.now_iso()
"""When this session started: its records share it."""
_REPORTED = pytest.StashKey[tuple[str, str, dict[str, Any]]]()


class RowReport:
    """What a fault-matrix test measured, against what bound: printed at once (``-s`` shows
    the figures as the run goes), recorded with the verdict once the test ended."""

    def __init__(self, item: pytest.Item) -> None:
        self.item = item
        self.kind, self.case = _kind_and_case(item)

    def __call__(self, measured: str, bound: str, figures: dict[str, Any] | None = None) -> None:
        """Report ``measured`` (one line of figures) against ``bound``, with the figures."""
        case = f" {self.case}" if self.case else ""
        print(f"\nrow {row_of(self.item)} [{self.kind}]{case}: {measured}")
        self.item.stash[_REPORTED] = (bound, measured, figures or {})


def record(item: pytest.Item, row: str, report: pytest.TestReport, call: Any) -> None:
    """Append the record of ``item`` (of fault-matrix row ``row``) with the verdict of
    ``report``; render the report again. Nothing for a skipped test (nothing measured)."""
    if hasattr(report, "wasxfail"):
        verdict = f"xfail: {report.wasxfail}"
    elif report.passed:
        verdict = "passed"
    elif report.failed:
        why = str(call.excinfo.value) if call.excinfo is not None else ""
        name = type(call.excinfo.value).__name__ if call.excinfo is not None else ""
        outcome = "failed" if report.when == "call" else "error"
        verdict = f"{outcome}: {name}: {why}".strip()
    else:
        return  # skipped: nothing was measured
    bound, measured, figures = item.stash.get(_REPORTED, ("", "", {}))
    kind, case = _kind_and_case(item)
    entry = labrows.RowRecord(
        run=RUN,
        date=runinfo.now_iso(),
        host=runinfo.host(),
        cpu=runinfo.cpus(),
        load=runinfo.load(),
        row=row,
        test=f"{item.path.name}::{getattr(item, 'originalname', item.name)}",
        case=case,
        kind=kind,
        bound=bound,
        measured=measured,
        verdict=verdict,
        figures=figures,
    )
    labrows.append(entry)
    labrows.write_report()


def row_of(item: pytest.Item) -> str | None:
    """The fault-matrix row the test's module names (None: not a row)."""
    module = getattr(item, "module", None)
    return getattr(module, "ROW", None)


def _kind_and_case(item: pytest.Item) -> tuple[str, str]:
    """The kind a test runs for (``arm`` unless parametrized) and its other parameters' ids."""
    callspec = getattr(item, "callspec", None)
    if callspec is None:
        return "arm", ""
    kind = callspec.params.get("kind")
    name = kind.name if kind is not None else "arm"
    ids = callspec.id.split("-")
    return name, "-".join(i for i in ids if kind is None or i != name)
