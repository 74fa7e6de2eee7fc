"""A choreography skips an isolated late target and aborts on a run of them."""

from __future__ import annotations

from fleet.choreo.player import MAX_LATE_IN_A_ROW, LateTargets


def test_late_targets_are_skipped_until_a_run_of_them_per_unit() -> None:
    late = LateTargets()
    assert MAX_LATE_IN_A_ROW == 3
    assert late.tolerable("a1") and late.tolerable("a1")
    late.taken("a1")  # a taken target ends the run
    assert late.tolerable("a1") and late.tolerable("a1")
    assert late.tolerable("g1 h1")  # each unit counts its own
    assert not late.tolerable("a1")  # the third in a row: abort
