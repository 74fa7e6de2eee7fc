"""The results pages made from the tools' outputs: the network lab's row records and their
table (``testkit.labrows``), the contact benchmark's report (``bench.contact_report``) and the
script that copies each output into its page (``scripts/docs_results.py``). Pure: records and
pages are built here or read from the tree, files written to ``tmp_path`` only."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import msgspec
import pytest

from bench import contact_report
from testkit import labrows

ROOT = Path(__file__).resolve().parents[2]


def _docs_results() -> ModuleType:
    spec = importlib.util.spec_from_file_location("docs_results", ROOT / "scripts/docs_results.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _record(**changes: object) -> labrows.RowRecord:
    base = labrows.RowRecord(
        run="2026-11-26T10:00:00+00:00",
        date="2026-11-26T10:03:00+00:00",
        host="vm",
        cpu="2 x Xeon",
        load=(3.0, 4.0, 5.0),
        row="1",
        test="test_stop_under_loss.py::test_every_stop",
        case="loss0",
        kind="arm",
        bound="received p99 <= 100 ms",
        measured="received p99 90 ms",
        verdict="passed",
        figures={"stops": 3},
    )
    return msgspec.structs.replace(base, **changes)


def test_the_newest_record_of_each_row_test_case_and_kind_wins() -> None:
    old = _record(measured="old", date="2026-11-25T10:00:00+00:00")
    new = _record(measured="new")
    other_kind = _record(kind="g1", measured="g1's")
    shown = labrows.newest([old, other_kind, new])
    assert [(r.kind, r.measured) for r in shown] == [("arm", "new"), ("g1", "g1's")]


def test_rows_are_ordered_by_row_then_test_kind_and_case_as_first_run() -> None:
    records = [
        _record(row="5", test="test_frozen.py::t", case=""),
        _record(row="1", case="loss0", kind="arm"),
        _record(row="1", case="loss0", kind="gripper"),
        _record(row="1", case="loss10", kind="arm"),
        _record(row="1", case="loss10", kind="gripper"),
        _record(row="2", test="test_watchdog.py::t", case="kill"),
        _record(row="1", test="test_watchdog_under_loss.py::t", case=""),
    ]
    order = [(r.row, r.test.split(".")[0], r.kind, r.case) for r in labrows.newest(records)]
    assert order == [
        ("1", "test_stop_under_loss", "arm", "loss0"),
        ("1", "test_stop_under_loss", "arm", "loss10"),
        ("1", "test_stop_under_loss", "gripper", "loss0"),
        ("1", "test_stop_under_loss", "gripper", "loss10"),
        ("1", "test_watchdog_under_loss", "arm", ""),
        ("2", "test_watchdog", "arm", "kill"),
        ("5", "test_frozen", "arm", ""),
    ]


def test_the_table_names_its_runs_and_each_rows_verdict_and_load() -> None:
    records = [
        _record(load=(2.5, 1.0, 1.0)),
        _record(kind="gripper", load=(7.25, 1.0, 1.0), verdict="xfail: still > 600 ms"),
        _record(kind="g1", verdict="failed: AssertionError: g1 moved | twice\nlog tail"),
    ]
    text = labrows.render(records)
    lines = text.splitlines()
    assert "2026-11-26 10:00 on `vm` (2 x Xeon): 3 rows, load average 2.5-7.2" in lines[0]
    assert lines[2].startswith("| row | test | kind | bound | measured | verdict |")
    arm, gripper, g1 = lines[4:7]
    assert "| 1 | `test_stop_under_loss.py` `test_every_stop` `[loss0]` | arm |" in arm
    assert "| **pass** | 2026-11-26 10:03 (2.5) |" in arm
    assert "| XFAIL: still > 600 ms |" in gripper
    # A failure shows its first line, its pipes escaped (one cell, one line).
    assert "| **FAILED**: AssertionError: g1 moved \\| twice |" in g1
    assert "log tail" not in text


def test_a_long_failure_is_cut_and_an_empty_file_says_how_to_fill_it() -> None:
    verdict = labrows.verdict_text("failed: " + "x" * 1000)
    assert len(verdict) < labrows.FAILURE_CHARS + 20 and verdict.endswith("...")
    assert "pytest tests/netlab" in labrows.render([])


def test_records_round_trip_and_a_half_written_line_is_skipped(tmp_path: Path) -> None:
    rows, report = tmp_path / "netlab" / "rows.jsonl", tmp_path / "netlab" / "report.md"
    labrows.append(_record(), rows)
    labrows.append(_record(kind="g1", figures={"still_ms": [float("inf")]}), rows)
    with rows.open("a", encoding="utf-8") as out:
        out.write('{"run": "2026-11-26T11:00:00+00:00", "row"')  # a run killed mid-write
    records, bad = labrows.read(rows)
    assert [r.kind for r in records] == ["arm", "g1"] and bad == 1
    assert records[1].figures == {"still_ms": [None]}  # JSON has no infinity
    text = labrows.write_report(rows, report)
    assert report.read_text(encoding="utf-8") == text
    assert "(1 unreadable lines skipped)" in text


def test_the_contact_report_names_the_run_above_its_table() -> None:
    figures = {
        "stall_recall": 100.0, "grip_recall": 98.55, "push_recall": 100.0,
        "false_alarms": 1.0, "fa_per_h": 0.42, "free_force_limits": 0.0,
        "p50_ms": 147.4, "p95_ms": 235.6,
    }  # fmt: skip
    row = contact_report.table_row("rate 60", "calibrated", figures)
    assert row == "| rate 60 | calibrated | 100.0% | 98.5% | 100.0% | 1 (0.4) | 0 | 147 / 236 |"
    run = contact_report.ContactRun(
        "2026-11-26T10:00:00+00:00", "vm, 2 x Xeon, Python 3.11.7", 7,
        {"free": 107, "stall": 72}, ("2", "3"), (6.7, 5.0, 4.0), (1.7, 2.0, 4.9), 896.4,
    )  # fmt: skip
    text = contact_report.markdown(run, [row])
    header, blank, head, rule, *rows = text.splitlines()
    assert "(2026-11-26 10:00, vm, 2 x Xeon, Python 3.11.7; seed 7)" in header
    assert "179 episodes per family and configuration (107 free, 72 stall)" in header
    assert "2+3" in header and "896 s" in header and "6.7 5.0 4.0 at the start" in header
    assert blank == "" and (head + "\n" + rule) == contact_report.HEAD and rows == [row]


@pytest.mark.parametrize(
    ("page", "source"),
    [
        ("docs/results/fault-matrix.md", "artifacts/netlab/report.md"),
        ("docs/results/contact.md", "artifacts/contact/report.md"),
    ],
)
def test_each_generated_page_has_its_outputs_markers(page: str, source: str) -> None:
    docs_results = _docs_results()
    assert docs_results.PAGES[page] == source
    text = (ROOT / page).read_text(encoding="utf-8")
    assert docs_results.BEGIN.format(source=source) in text and docs_results.END in text


def test_a_refresh_replaces_only_the_generated_part(tmp_path: Path) -> None:
    docs_results = _docs_results()
    source, page = "artifacts/netlab/report.md", "docs/results/fault-matrix.md"
    begin = docs_results.BEGIN.format(source=source)
    old = f"# Head\n\nhand-written\n\n{begin}\n\nold table\n\n{docs_results.END}\n\n## Tail\n"
    (tmp_path / page).parent.mkdir(parents=True)
    (tmp_path / page).write_text(old, encoding="utf-8")
    assert docs_results.refreshed(page, source, tmp_path) is None  # no output: page kept
    (tmp_path / source).parent.mkdir(parents=True)
    (tmp_path / source).write_text("| new | table |\n", encoding="utf-8")
    new = docs_results.refreshed(page, source, tmp_path)
    assert new == old.replace("old table", "| new | table |")
    with pytest.raises(SystemExit, match="markers"):
        docs_results.replaced(page, "# no markers\n", source, "x")
