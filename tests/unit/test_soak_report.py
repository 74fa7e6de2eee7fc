"""The soak's pure parts (``bench/soak.py``, ``bench/soak_report.py``): duration parsing and the
goal arithmetic, on synthetic records. The soak itself runs with ``make soak``."""

from __future__ import annotations

import argparse

import pytest

from bench.soak import parse_duration
from bench.soak_report import SoakRecord, markdown, process_rows


@pytest.mark.parametrize(
    ("text", "seconds"), [("90s", 90), ("5m", 300), ("30m", 1800), ("1.5h", 5400), ("45", 45)]
)
def test_durations(text: str, seconds: float) -> None:
    assert parse_duration(text) == seconds


@pytest.mark.parametrize("text", ["", "5 min", "-3m", "10s", "m"])
def test_bad_durations(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        parse_duration(text)


def _record(growth_mib: float, confirmed: bool = True) -> SoakRecord:
    record = SoakRecord(duration_s=1000.0, period_s=30.0)
    for i in range(201):  # every 5 s; warm-up ends at 200 s, windows are 100 s
        t = 5.0 * i
        rss = 100.0 if t < 900 else 100.0 + growth_mib
        record.add_sample("agent-a1", 1, t, rss, 2.0)
        record.add_sample("agent-a2", 2, t, 50.0 + t, 1.0)  # restarted: not judged
    record.stops.append({"t": 30.0, "written_ms": 3.0, "still_ms": 300.0, "call_ms": 400.0,
                         "confirmed": confirmed, "moving_deg": 4.0})  # fmt: skip
    return record


def test_growth_is_end_window_over_after_warm_up_window() -> None:
    record = _record(growth_mib=4.0)
    rows = {r.role: r for r in process_rows(record, {"agent-a1": 1, "agent-a2": 2})}
    assert rows["agent-a1"].rss_warm == 100.0 and rows["agent-a1"].rss_end == 104.0
    assert rows["agent-a1"].growth_pct == 4.0 and rows["agent-a1"].passed
    assert not rows["agent-a2"].judged and rows["agent-a2"].passed
    text, passed = markdown(record, list(rows.values()))
    assert passed, text


def test_a_missed_goal_fails_the_soak() -> None:
    record = _record(growth_mib=6.0)
    _text, passed = markdown(record, process_rows(record, {"agent-a1": 1, "agent-a2": 2}))
    assert not passed
    record = _record(growth_mib=0.0, confirmed=False)
    text, passed = markdown(record, process_rows(record, {"agent-a1": 1, "agent-a2": 2}))
    assert not passed and "every stop confirmed (0 of 1)" in text
