"""The coordinator's record of latched stops: what every heartbeat repeats (pure)."""

from __future__ import annotations

from fleet.coordinator.stops import FLEET, StopBook
from fleet.wire import messages as m


def _stop(stop_id: str) -> m.StopRequest:
    return m.StopRequest(stamp_ns=1, source="test", stop_id=stop_id)


def test_the_newest_fleet_stop_is_repeated() -> None:
    book = StopBook(["a1", "a2"])
    book.on_stop(FLEET, _stop("s1"))
    book.on_reset("a1")
    book.on_reset("a2")
    assert FLEET not in book.latched()  # every arm was reset one by one
    book.on_stop(FLEET, _stop("s2"))
    assert book.latched()[FLEET].stop_id == "s2"


def test_a_partial_reset_keeps_the_fleet_stop() -> None:
    book = StopBook(["a1", "a2"])
    book.on_stop(FLEET, _stop("s1"))
    book.on_stop("a2", _stop("s2"))
    book.on_reset("a1")
    assert book.latched()[FLEET].stop_id == "s1"
    assert book.latched()["a2"].stop_id == "s2"
    book.on_reset(FLEET)
    assert book.latched() == {}
