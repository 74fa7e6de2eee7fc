"""The agent's latch files (``edge_agent/latches.py``) on a real file system, no agent: keyed by
fleet and DDS domain, an older agent's file read once, never through a symbolic link, and a
write that fails counted and reported."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from edge_agent.latches import LatchDirError, LatchStore, latch_dir
from fleet.guard import ThreadGuard
from fleet.wire import messages as m
from testkit.harness import wait_until

STOP = m.StopRequest(stamp_ns=1, source="test", stop_id="s1", reason="why")


class Outcomes(dict[str, "str | None"]):
    """What the store reported per unit (the agent puts it in the unit's status)."""

    def __call__(self, unit: str, why: str | None) -> None:
        self[unit] = why


@pytest.fixture
def stores(tmp_path: Path) -> Iterator[list[LatchStore]]:
    """Stores to close at the end (their directory descriptors)."""
    opened: list[LatchStore] = []
    yield opened
    for store in opened:
        store.close()


def _store(
    stores: list[LatchStore], state: Path, domain: int = 7, fleet: str = "lab"
) -> tuple[LatchStore, Outcomes]:
    outcomes = Outcomes()
    store = LatchStore(state, fleet, domain, ThreadGuard("test"), outcomes)
    stores.append(store)
    return store, outcomes


def test_fleets_named_alike_on_other_domains_never_share_a_latch(
    tmp_path: Path, stores: list[LatchStore]
) -> None:
    lab7, _ = _store(stores, tmp_path, domain=7)
    lab8, _ = _store(stores, tmp_path, domain=8)
    lab7.save("a1", STOP)
    assert lab7.load("a1") == STOP
    assert lab8.load("a1") is None
    assert (latch_dir(tmp_path, "lab", 7) / "a1.stop.json").is_file()
    lab8.clear("a1")  # the other fleet's reset releases nothing here
    assert lab7.load("a1") == STOP


def test_an_older_agents_latch_is_read_once_and_moved(
    tmp_path: Path, stores: list[LatchStore]
) -> None:
    old = tmp_path / "lab" / "a1.stop.json"
    old.parent.mkdir(parents=True)
    old.write_bytes(m.encode(STOP))
    store, _ = _store(stores, tmp_path)
    assert store.load("a1") == STOP
    assert not old.exists()
    assert store.load("a1") == STOP  # now from its new place
    store.clear("a1")
    assert store.load("a1") is None


def test_an_undecodable_old_latch_latches_until_a_reset_removes_it(
    tmp_path: Path, stores: list[LatchStore]
) -> None:
    old = tmp_path / "lab" / "a1.stop.json"
    old.parent.mkdir(parents=True)
    old.write_bytes(b"not json")
    store, _ = _store(stores, tmp_path)
    restored = store.load("a1")
    assert restored is not None and "unreadable" in restored.reason
    assert store.load("a1") is not None  # moved as it was: the next start latches again
    store.clear("a1")
    assert not old.exists() and store.load("a1") is None


@pytest.mark.parametrize("entry", ["fleet", "domain"])
def test_a_symlinked_latch_directory_is_refused(
    tmp_path: Path, stores: list[LatchStore], entry: str
) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    link = tmp_path / "state" / "lab"
    if entry == "domain":
        link.mkdir(parents=True)
        link = link / "domain-7"
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(elsewhere)
    with pytest.raises(LatchDirError, match="symbolic link"):
        _store(stores, tmp_path / "state")
    assert list(elsewhere.iterdir()) == []


def test_latch_files_are_never_read_or_written_through_a_link(
    tmp_path: Path, stores: list[LatchStore]
) -> None:
    store, outcomes = _store(stores, tmp_path)
    target = tmp_path / "target"
    target.write_bytes(m.encode(STOP))
    here = latch_dir(tmp_path, "lab", 7)
    (here / "a1.stop.json").symlink_to(target)
    (here / "a2.stop.tmp").symlink_to(target)
    # A linked latch file is refused, and latches (fail safe), its target unread.
    restored = store.load("a1")
    assert restored is not None and restored.stop_id != STOP.stop_id
    assert "symbolic link" in restored.reason
    other = m.StopRequest(stamp_ns=2, source="test", stop_id="s2", reason="")
    store.save("a1", other)  # the link is replaced, never written through
    store.save("a2", other)  # a link planted as the temporary file: removed first
    assert target.read_bytes() == m.encode(STOP)
    assert not (here / "a1.stop.json").is_symlink() and store.load("a1") == other
    assert store.load("a2") == other
    assert outcomes == {"a1": None, "a2": None} and store.failures == 0


def test_a_failed_write_is_counted_reported_and_retried(
    tmp_path: Path, stores: list[LatchStore]
) -> None:
    store, outcomes = _store(stores, tmp_path)
    # A directory where the temporary file goes: it cannot be removed or opened as a file.
    (latch_dir(tmp_path, "lab", 7) / "a1.stop.tmp").mkdir()
    store.save("a1", STOP)
    assert store.failures == 1
    assert outcomes["a1"] is not None and "a1.stop.json" in outcomes["a1"]
    assert store.load("a1") is None
    store.save("a1", STOP)  # a retry of the same stop: counted once
    assert store.failures == 1
    os.rmdir(latch_dir(tmp_path, "lab", 7) / "a1.stop.tmp")
    store.thread.start()  # its retry writes the stop once the disk lets it
    wait_until(lambda: outcomes["a1"] is None, 5.0)
    assert store.load("a1") == STOP and store.failures == 1
