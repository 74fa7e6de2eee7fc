"""Devices in the coordinator (issue 14): the fleet state lists every device (online, link,
stop, its kind's summary), a fleet stop's report carries the devices' timings, and
``fleet status --json`` gives each device's state under ``<kind>/<id>``. Real processes: a
router, ``fleet sim`` (one arm, a gripper and a G1), one devices agent, the coordinator."""

from __future__ import annotations

from fleet.coordinator.state import FleetStateTracker
from fleet.coordinator.stops import StopBook
from fleet.wire import messages as m
from fleet.wire import payloads

EXTRA = '[grippers.gl]\nmount = "a1"\n\n[g1.h1]\n'


def test_tracker_device_online_needs_token_and_a_recent_state() -> None:
    tracker = FleetStateTracker(["a1"], 1.0, {"gl": "gripper"})
    assert tracker.device_summary("gl", 0.0) == m.DeviceSummary("gripper", False, "lost")
    tracker.on_device_state("gl", "ok", False, "open 50 %", 1.0)
    assert not tracker.device_summary("gl", 1.0).online  # no agent token
    tracker.on_device_token("gl", True, 1.0)
    line = tracker.device_summary("gl", 1.5)
    assert (line.online, line.link, line.summary) == (True, "ok", "open 50 %")
    assert tracker.device_summary("gl", 2.6).link == "lost"  # silent for 1.6 s > 1 s
    tracker.on_device_state("nobody", "ok", False, "x", 3.0)  # unknown: ignored
    state = tracker.state("c", 3.0, 1)
    assert set(state.devices) == {"gl"} and set(state.arms) == {"a1"}


def test_fleet_state_without_devices_still_decodes() -> None:
    old = b'{"stamp_ns": 1, "coordinator": "c", "arms": {}}'
    assert payloads.STATE.decode(old).devices == {}


def test_stop_report_includes_device_acks_but_device_resets_do_not_release_arms() -> None:
    book = StopBook(["a1"], devices=["gl"])
    request = m.StopRequest(stamp_ns=1_000_000, source="t", stop_id="s1")
    book.on_stop("*", request)
    ack = m.StopAck(
        arm="gl",
        stop_id="s1",
        action="hold",
        received_ns=2_000_000,
        dds_written_ns=None,
        still_ns=None,
    )
    report = book.on_ack("gl", ack)
    assert report is not None and report.arms["gl"].received_ms == 1.0
    book.on_reset("a1")
    assert book.latched() == {}  # every arm reset one by one releases the fleet stop
    assert book.on_ack("nobody", ack) is None
