"""Issue 28, finding 5: heartbeats are bounded before they are parsed (size, rate per principal),
so a flood of 4 MB heartbeats (open mode) keeps stop -> ack within 2x its quiet figure: its
median and its worst stop (``testkit.stoptimes.flood_goals_missed``)."""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

from edge_agent.inbox import InboxCounters, SafetyInbox
from fleet.beat_limits import BEATS_PER_S, BeatGate, max_heartbeat_bytes
from fleet.client import FleetClient
from fleet.security.session import open_session
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.harness import FleetHarness, wait_until
from testkit.load import xfail_if_overloaded
from testkit.stoptimes import StopTimes, flood_goals_missed

STOPS = 15
FLOODERS = 3


def _beat(stops: int = 0) -> bytes:
    request = m.StopRequest(stamp_ns=1, source="c", stop_id="s", reason="x" * 1024)
    return m.encode(m.Heartbeat(1, "c", 0, 0.1, {f"a{i}": request for i in range(stops)}))


def test_a_full_heartbeat_fits_its_bound() -> None:
    assert len(_beat(stops=3)) <= max_heartbeat_bytes(1)  # a1 and the fleet (+1 spare)


def test_a_principal_is_rate_bounded_others_are_not() -> None:
    now = [0.0]
    gate = BeatGate(clock=lambda: now[0])
    admitted = sum(gate.admit("eve") for _ in range(10 * int(BEATS_PER_S)))
    assert admitted == int(BEATS_PER_S)  # the burst, then nothing within the same instant
    assert gate.admit("coordinator")
    now[0] = 0.1
    assert 15 <= sum(gate.admit("eve") for _ in range(100)) <= 25  # refilled at its rate


def test_the_inbox_drops_big_beats_unread() -> None:
    counters = InboxCounters()
    inbox = SafetyInbox(counters, max_beat_bytes=4096)
    inbox.on_heartbeat("eve", b"{" + b" " * 8192)
    assert counters.dropped_events == 1 and counters.bad_payloads == 0  # never parsed
    inbox.on_heartbeat("ann", _beat())
    assert [source for source, _b, _t in inbox.take()[1]] == ["ann/c"]


def _stop_latencies(h: FleetHarness, client: FleetClient) -> list[float]:
    """Stop put -> its first ack received (ms), ``STOPS`` times (a reset between)."""
    acked: dict[str, float] = {}
    arrived = threading.Condition()

    def on_ack(sample: zenoh.Sample) -> None:
        ack = payloads.STOP_ACK.decode(sample.payload.to_bytes())
        with arrived:
            acked.setdefault(ack.stop_id, time.monotonic())
            arrived.notify_all()

    sub = client.session.declare_subscriber(client.keys.arm("a1", keys.ESTOP_ACK), on_ack)
    out = []
    try:
        for _ in range(STOPS):
            request = client.stop_request("flood test")
            started = time.monotonic()
            client.put_stop(request, "a1")
            with arrived:
                assert arrived.wait_for(lambda r=request: r.stop_id in acked, 5.0), h.diagnose(
                    client
                )
            out.append((acked[request.stop_id] - started) * 1000)
            client.reset("a1")
            wait_until(lambda: _released(client), 5.0)
    finally:
        sub.undeclare()
    return out


@pytest.mark.timing
def test_stop_to_ack_under_a_flood_of_huge_heartbeats(fleet_harness: FleetHarness) -> None:
    h = fleet_harness
    client = h.start_fleet()
    quiet = StopTimes(_stop_latencies(h, client))
    done = threading.Event()
    flooded = [0]
    huge = b'{"stamp_ns":1,"coordinator":"x","seq":0,"period_s":0.1,"stops":{},"x":"'
    huge += b"z" * ((4 << 20) - 200) + b'"}'

    def flood() -> None:
        with open_session(h.inventory) as session:
            pub = session.declare_publisher(
                client.keys.heartbeat_of("eve"),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            while not done.is_set():
                pub.put(huge)
                flooded[0] += 1

    threads = [threading.Thread(target=flood, daemon=True) for _ in range(FLOODERS)]
    for thread in threads:
        thread.start()
    try:
        under = StopTimes(_stop_latencies(h, client))
    finally:
        done.set()
        for thread in threads:
            thread.join(10.0)
    print(f"\nstop -> ack: quiet {quiet}; under the flood {under} ({flooded[0]} beats)")
    assert flooded[0] > 10
    assert h.processes["agent"].poll() is None
    late = flood_goals_missed(quiet, under)  # the worst stop too, not only the median
    xfail_if_overloaded(late)
    assert not late, f"{late}: {under.ms}"


def _released(client: FleetClient) -> bool:
    """a1's status says unlatched (a snapshot under the flood may come back without one)."""
    status = client.snapshot(wait_s=0.3)["a1"][0]
    return status is not None and not status.estopped
