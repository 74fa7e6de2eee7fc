"""SeqAllocator: unique seqs among the commands in flight, never the arm's own 10."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fleet.d1.protocol import ARM_REPORT_SEQ
from fleet.d1.seq import SEQ_FIRST, SEQ_LAST, SeqAllocator, SeqExhausted


def test_default_range_starts_at_first_and_skips_10() -> None:
    seqs = SeqAllocator()
    got = [seqs.allocate() for _ in range(20)]
    assert got[0] == SEQ_FIRST
    assert ARM_REPORT_SEQ not in got
    assert got == [s for s in range(1, 22) if s != 10]


def test_never_returns_10_over_many_wraps() -> None:
    seqs = SeqAllocator(5, 15)
    for _ in range(200):
        seq = seqs.allocate()
        assert seq != ARM_REPORT_SEQ
        assert 5 <= seq <= 15
        seqs.release(seq)


def test_wraps_to_first_after_last() -> None:
    seqs = SeqAllocator(1, 4)
    got = []
    for _ in range(9):
        seq = seqs.allocate()
        got.append(seq)
        seqs.release(seq)
    assert got == [1, 2, 3, 4, 1, 2, 3, 4, 1]


def test_default_range_wraps_at_the_top() -> None:
    seqs = SeqAllocator()
    for _ in range(SEQ_LAST - SEQ_FIRST):  # every usable seq but one (10 is skipped)
        seqs.release(seqs.allocate())
    assert seqs.allocate() == SEQ_FIRST


def test_skips_seqs_still_in_flight() -> None:
    seqs = SeqAllocator(1, 4)
    a, b = seqs.allocate(), seqs.allocate()  # 1, 2
    seqs.release(a)
    c, d = seqs.allocate(), seqs.allocate()  # 3, 4
    assert (a, b, c, d) == (1, 2, 3, 4)
    # 1 is free again, 2 still in flight: the wrap must skip 2.
    assert seqs.allocate() == 1
    with pytest.raises(SeqExhausted):
        seqs.allocate()
    assert seqs.in_flight == {1, 2, 3, 4}


def test_exhausted_when_all_in_flight_and_recovers_after_release() -> None:
    seqs = SeqAllocator(8, 12)  # usable: 8, 9, 11, 12
    got = {seqs.allocate() for _ in range(4)}
    assert got == {8, 9, 11, 12}
    with pytest.raises(SeqExhausted):
        seqs.allocate()
    seqs.release(11)
    assert seqs.allocate() == 11
    with pytest.raises(SeqExhausted):
        seqs.allocate()


def test_release_of_unknown_seq_is_harmless() -> None:
    seqs = SeqAllocator(1, 3)
    seqs.release(2)
    seqs.release(99)
    assert seqs.in_flight == frozenset()


@pytest.mark.parametrize(("first", "last"), [(-1, 5), (5, 5), (6, 5)])
def test_bad_range_is_refused(first: int, last: int) -> None:
    with pytest.raises(ValueError):
        SeqAllocator(first, last)


@given(
    ops=st.lists(st.one_of(st.just("alloc"), st.integers(min_value=0, max_value=15)), max_size=80)
)
def test_allocations_are_unique_among_those_in_flight(ops: list[object]) -> None:
    seqs = SeqAllocator(7, 14)  # 7 usable seqs
    model: set[int] = set()
    for op in ops:
        if op == "alloc":
            if len(model) == 7:
                with pytest.raises(SeqExhausted):
                    seqs.allocate()
                continue
            seq = seqs.allocate()
            assert seq != ARM_REPORT_SEQ and 7 <= seq <= 14
            assert seq not in model
            model.add(seq)
        else:
            assert isinstance(op, int)
            seqs.release(op)
            model.discard(op)
        assert seqs.in_flight == model
