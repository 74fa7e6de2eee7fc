"""Issue 28, finding 1: stops and resets are applied in arrival order in every process that
takes both (the agent's relay, the coordinator, the viewer), through the one shared intake
(``fleet.control``). Hundreds of stop/reset pairs, back to back, on the fleet's and an arm's
keys, from one publisher: each process must see exactly the order they were put in."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import zenoh

from edge_agent.inbox import CommandInbox, InboxCounters, ResetEvent, SafetyInbox, StopEvent
from edge_agent.relay import ZenohRelay
from fleet.client import STOP_QOS
from fleet.control import ControlFifo
from fleet.coordinator.intake import Control
from fleet.coordinator.service import Coordinator
from fleet.guard import ThreadGuard
from fleet.record.reader import read_recording
from fleet.record.recorder import Recorder
from fleet.security.session import open_session
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.session import Datagram
from testkit.harness import FleetHarness, wait_until
from viewer.state import ViewerFleet

PAIRS = 300
JSON = zenoh.Encoding.APPLICATION_JSON


def test_the_fifo_keeps_order_and_never_loses_a_stop() -> None:
    fifo: ControlFifo[tuple[str, object]] = ControlFifo(lambda t: ("flood", t), depth=4)
    for i in range(3):
        assert fifo.push(("stop", i), None, is_stop=True)
    assert fifo.push(("reset", 3))
    assert not fifo.push(("reset", 4))  # full: a reset is dropped (the latch holds)
    assert not fifo.push(("stop", 5), "a1", is_stop=True)  # full: its target is marked
    assert fifo.take() == [("stop", 0), ("stop", 1), ("stop", 2), ("reset", 3), ("flood", "a1")]
    assert fifo.take() == []


def _sequence() -> list[tuple[str, str | None, int]]:
    """What is put, in order: (kind, arm, index), fleet keys and a1's keys alternating."""
    out = []
    for i in range(PAIRS):
        arm = None if i % 2 == 0 else "a1"
        out += [("reset", arm, i), ("stop", arm, i)]
    return out


def _put_all(h: FleetHarness) -> list[tuple[str, str | None, int]]:
    """Put the whole sequence from one session, once every key has a subscriber."""
    space = keys.KeySpace(h.inventory.fleet)
    sequence = _sequence()
    with open_session(h.inventory) as session:
        pubs = {
            (kind, arm): session.declare_publisher(key, encoding=JSON, **STOP_QOS)  # type: ignore[arg-type]
            for kind, arm, key in (
                ("stop", None, space.estop),
                ("reset", None, space.reset),
                ("stop", "a1", space.arm("a1", keys.ESTOP)),
                ("reset", "a1", space.arm("a1", keys.RESET)),
            )
        }
        wait_until(lambda: all(p.matching_status.matching for p in pubs.values()), 10.0)
        for kind, arm, i in sequence:
            if kind == "stop":
                payload = m.encode(m.StopRequest(stamp_ns=i + 1, source="t", stop_id=f"s{i}"))
            else:
                payload = m.encode(m.ResetRequest(stamp_ns=i + 1, source=f"r{i}"))
            pubs[(kind, arm)].put(payload)
        for pub in pubs.values():
            pub.undeclare()
    return sequence


@pytest.fixture
def router(fleet_harness: FleetHarness) -> Iterator[FleetHarness]:
    fleet_harness.start_router()
    yield fleet_harness


def test_the_coordinator_applies_them_in_order(router: FleetHarness) -> None:
    seen: list[tuple[str, str | None, int]] = []
    with Coordinator(router.inventory) as coordinator:
        apply = coordinator._apply_control  # noqa: SLF001 - the order it applies is the point

        def record(event: Control, now: float) -> None:
            if event.kind == "stop" and event.stop is not None:
                seen.append(("stop", event.arm, int(event.stop.stop_id[1:])))
            elif event.kind == "reset":
                seen.append(("reset", event.arm, -1))
            apply(event, now)

        coordinator._apply_control = record  # type: ignore[method-assign]  # noqa: SLF001
        coordinator.start()
        sequence = _put_all(router)
        wait_until(lambda: len(seen) >= len(sequence), 20.0)
        assert not coordinator.failed.is_set()
    # a reset carries no id to the coordinator: its place between the stops is the check
    assert [(k, a) for k, a, _ in seen] == [(k, a) for k, a, _ in sequence]
    assert [i for k, _, i in seen if k == "stop"] == list(range(PAIRS))


def test_the_agent_takes_them_in_order(router: FleetHarness) -> None:
    counters = InboxCounters()
    safety = SafetyInbox(counters)
    commands = CommandInbox(counters, lambda _q: None, lambda _k: None)
    guard = ThreadGuard("test-agent")
    # The reliable path's order (what the intake keeps); the datagram path's copies of the stops
    # arrive in any order beside it, which the latch's stamps handle (test_kinds_safety's race,
    # test_stop_datagram): not this test's subject.
    reliable_only = msgspec.structs.replace(router.inventory, datagram=Datagram(False, None))
    relay = ZenohRelay(reliable_only, ["a1"], (safety, commands), guard)
    seen: list[tuple[str, str | None, int]] = []
    try:
        sequence = _put_all(router)

        def drained() -> bool:
            control, _beats = safety.take()
            for event in control:
                if isinstance(event, StopEvent) and event.request is not None:
                    seen.append(("stop", event.arm, int(event.request.stop_id[1:])))
                elif isinstance(event, ResetEvent):
                    seen.append(("reset", event.arm, int(event.request.source[1:])))
            return len(seen) >= len(sequence)

        wait_until(drained, 20.0)
    finally:
        relay.close()
    assert not guard.failed.is_set()
    assert seen == sequence


def test_the_viewer_logs_them_in_order(router: FleetHarness) -> None:
    with open_session(router.inventory) as session:
        state = ViewerFleet(("a1",), router.inventory.fleet, session)
        seen: list[tuple[str, str | None, int]] = []
        lock = threading.Lock()
        add = state.events.add

        def record(kind: str, arm: str | None, text: str, wall_ns: int | None = None) -> None:
            if text.startswith("reset requested by r"):
                with lock:
                    seen.append(("reset", arm, int(text.rsplit(" r", 1)[1])))
            elif text.startswith("stop requested by t"):
                with lock:
                    seen.append(("stop", arm, -1))
            add(kind, arm, text, wall_ns)

        state.events.add = record  # type: ignore[method-assign]
        state.start()
        sequence = _put_all(router)
        wait_until(lambda: len(seen) >= len(sequence), 20.0)
    assert [(k, a) for k, a, _ in seen] == [(k, a) for k, a, _ in sequence]
    assert [i for k, _, i in seen if k == "reset"] == list(range(PAIRS))


def test_the_recorder_writes_them_in_order(router: FleetHarness, tmp_path: Path) -> None:
    """Issue 28: the recorder takes stops and resets through the shared intake (it did not
    record resets at all, and its subscribers could reorder them)."""
    path = tmp_path / "order.mcap"
    with open_session(router.inventory) as session:
        space = keys.KeySpace(router.inventory.fleet)
        recorder = Recorder(session, space, ["a1"], path)
        try:
            sequence = _put_all(router)
            control = (space.estop, space.reset, space.arm("a1", keys.ESTOP))
            control += (space.arm("a1", keys.RESET),)
            wait_until(lambda: sum(recorder.counts.get(k, 0) for k in control) >= 2 * PAIRS, 20.0)
        finally:
            recorder.close()
    seen = []
    for r in read_recording(path).messages:
        parsed = space.parse_key(r.key)
        arm = parsed.unit or None
        if parsed.channel == keys.ESTOP:
            seen.append(("stop", arm, int(msgspec.json.decode(r.data)["stop_id"][1:])))
        elif parsed.channel == keys.RESET:
            seen.append(("reset", arm, int(msgspec.json.decode(r.data)["source"][1:])))
    assert seen == sequence
