"""The coordinator's beats go on the datagram path only while they may matter: while some
unit's watchdog watches the coordinator (its status or state says so: ``watched_by``) or a
stop is latched. An idle fleet's agents get each beat once, over TCP, and their datagram
sessions never take the missing copies for deafness. Every kind, far side: the agent's own
reports and the router's delivery to a plain subscriber."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import zenoh

from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.harness import FleetHarness, next_diag, wait_until
from testkit.kinds import KIND_IDS, KINDS, Kind, LatchWatch, devices_fleet, send, with_envelope


class Beats:
    """Every beat of the fleet's commanders, as a subscriber on a client session gets them:
    (arrival, beat) on TCP, and the arrival of each datagram copy."""

    def __init__(self, session: zenoh.Session, space: keys.KeySpace) -> None:
        self.reliable: list[tuple[float, m.Heartbeat]] = []
        self.copies: list[float] = []
        beats = f"{space.prefix}/{keys.HEARTBEAT}/*"
        self._subscribers = [
            session.declare_subscriber(beats, self._on_beat),
            session.declare_subscriber(keys.datagram_key(beats), self._on_copy),
        ]

    def _on_beat(self, sample: zenoh.Sample) -> None:
        beat = payloads.HEARTBEAT.decode(sample.payload.to_bytes())
        self.reliable.append((time.monotonic(), beat))

    def _on_copy(self, _sample: zenoh.Sample) -> None:
        self.copies.append(time.monotonic())

    def copies_since(self, since: float) -> int:
        return sum(1 for t in list(self.copies) if t >= since)

    def announced_since(self, since: float) -> list[int]:
        return [b.datagram_copies for t, b in list(self.reliable) if t >= since]

    def quiet(self, for_s: float) -> bool:
        """No copy for ``for_s``, and the newest beat announces none."""
        now = time.monotonic()
        beats = self.announced_since(now - for_s)
        return self.copies_since(now - for_s) == 0 and bool(beats) and beats[-1] == 0

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()  # type: ignore[no-untyped-call]


def _idle_then_quiet(beats: Beats) -> None:
    """Two seconds of an idle fleet: every beat over TCP only, announcing no copy."""
    wait_until(lambda: beats.quiet(0.5), 30.0, explain=lambda: f"{beats.copies[-3:]}")
    start = time.monotonic()
    wait_until(lambda: len(beats.announced_since(start)) >= 20, 10.0)
    assert set(beats.announced_since(start)) == {0}
    assert beats.copies_since(start) == 0


@pytest.mark.parametrize("kind", KINDS, ids=KIND_IDS)
def test_beats_take_the_datagram_path_only_while_a_unit_watches_or_a_stop_is_latched(
    tmp_path: Path, kind: Kind
) -> None:
    with devices_fleet(tmp_path) as h:
        h.start_coordinator()
        client = h.client()
        beats = Beats(client.session, client.keys)
        watch = LatchWatch(client, kind)
        try:
            wait_until(watch.link_ok, 30.0)
            _idle_then_quiet(beats)
            coordinator = beats.reliable[-1][1].coordinator

            # A command in the coordinator's name (as the lab's stand-in sends the devices'):
            # the unit's watchdog watches it and says so, and the copies come.
            stand_in = h.client("coordinator")
            commanded = time.monotonic()
            outcome = send(stand_in, kind, with_envelope(kind.moves(), owner=coordinator))
            assert outcome.ok, outcome
            source = f"coordinator/{coordinator}"
            wait_until(lambda: (s := watch.latest()) is not None and s.watched_by == source, 5.0)
            wait_until(lambda: beats.copies_since(commanded) >= 4, 5.0)
            first = min(t for t in beats.copies if t >= commanded)
            print(
                f"{kind.name}: the first copy {1000 * (first - commanded):.0f} ms after the command"
            )
            assert 2 in beats.announced_since(first)

            # The watch ends (the command done, the lease over): the copies end, within the
            # coordinator's grace after the last report naming it.
            wait_until(lambda: (s := watch.latest()) is not None and s.watched_by is None, 60.0)
            wait_until(lambda: beats.quiet(1.0), 30.0)

            # A latched fleet stop rides in every beat: its copies go while it is latched.
            stopped = time.monotonic()
            client.estop(reason="test")
            wait_until(lambda: beats.copies_since(stopped) >= 4, 10.0)
            client.reset()
            wait_until(lambda: beats.quiet(1.0), 30.0)
        finally:
            beats.close()
        # No agent took the silent datagram path for a deaf one (nor replaced it).
        assert "deaf" not in h.log("agent")


def test_an_idle_arm_fleet_agent_hears_each_beat_once(fleet_harness: FleetHarness) -> None:
    """The arm's own agent (``edge-agent --arm``) counts what reached it: while idle, no
    datagram copy of a beat."""
    client = fleet_harness.start_fleet()
    fleet_harness.start_coordinator()
    beats = Beats(client.session, client.keys)
    try:
        _idle_then_quiet(beats)
    finally:
        beats.close()
    fleet = fleet_harness.inventory.fleet
    before = next_diag(client, fleet, "a1")
    after = wait_until(
        lambda: (d := next_diag(client, fleet, "a1")).stamp_ns > before.stamp_ns + 1.5e9 and d,
        10.0,
    )
    assert after.beat_copies_reliable - before.beat_copies_reliable >= 10
    assert after.beat_copies_datagram == before.beat_copies_datagram
