"""The viewer's pure parts for a shift: the replay timeline (seek both ways, speed, the end), the
recorded layout (hostile files refused, old files in a row), the event log (transitions, not
repeats; bounded), one arm's confirmation, and the camera's framing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fleet.record.errors import RecordError
from fleet.record.layout import (
    layout_from_keys,
    layout_from_metadata,
)
from fleet.record.reader import read_recording
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode
from testkit.recordings import write_recording
from viewer.camera import UP, camera_axes, fit_view, usable_right_edge
from viewer.confirm import FLEET, Confirmations
from viewer.events import MAX_EVENTS, EventLog
from viewer.replay import ReplayTimeline, replay_source
from viewer.state import ViewerFleet

SPACE = keys.KeySpace("lab")


def test_the_timeline_scrubs_both_ways_plays_at_speed_and_stops_at_the_end(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    write_recording(path)
    source = replay_source(read_recording(path))
    assert source.layout_recorded and tuple(source.layout.arms) == ("a1", "a2", "a3")
    assert all(keys.RAW_COMMAND not in r.key for r in source.messages)
    timeline = ReplayTimeline(source)
    assert timeline.duration_s == pytest.approx(5.0)

    timeline.request_seek(4.5)
    timeline.tick(0.05)
    snap = timeline.snapshot()
    assert snap.angles_deg[0, 0] == 45.0 and snap.status[0] is not None
    assert snap.status[0].estopped and bool(snap.contact_rows()[0, 2])
    assert bool(snap.online[0]) and not bool(snap.online[1])  # a2 has no status in the file
    kinds = [e.kind for e in timeline.events.newest()]
    assert kinds.count("stop") == 2  # the request once (5 repeats) and a1's latch
    assert "contact" in kinds

    timeline.request_seek(1.0)  # backwards: rebuilt from the start
    timeline.tick(0.05)
    snap = timeline.snapshot()
    assert snap.angles_deg[0, 0] == 10.0 and snap.status[0] is not None
    assert not snap.status[0].estopped and not snap.contact_rows().any()
    assert timeline.events.newest() == []

    timeline.set_speed(4.0)
    timeline.set_speed(3.0)  # not offered: ignored
    timeline.set_playing(True)
    timeline.tick(0.5)  # 0.5 s of wall time at 4x
    assert timeline.position_s == pytest.approx(3.0)
    timeline.tick(10.0)
    assert timeline.position_s == pytest.approx(5.0) and not timeline.playing
    timeline.set_playing(True)  # play at the end starts over
    timeline.tick(0.1)
    assert timeline.position_s == pytest.approx(0.0) and timeline.playing


def test_a_recording_without_a_layout_stands_its_arms_in_a_row(tmp_path: Path) -> None:
    path = tmp_path / "old.mcap"
    write_recording(path, layout=False)
    source = replay_source(read_recording(path))
    assert not source.layout_recorded and tuple(source.layout.arms) == ("a1",)
    assert layout_from_keys(["fleet/lab/arm/a2/joints", "fleet/lab/arm/a1/joints"]) is not None
    assert layout_from_keys(["fleet/lab/estop", "junk"]) is None


@pytest.mark.parametrize(
    "text",
    [
        '{"fleet": "lab", "arms": {"a1": {"base_xyz": [1e999, 0, 0]}}}',
        '{"fleet": "lab", "arms": {"a1": {"joint_sign": [1, 1, 2, 1, 1, 1, 1]}}}',
        '{"fleet": "lab", "arms": {"a1": {"joint_sign": [1]}}}',
        '{"fleet": "lab", "arms": {"a/1": {}}}',
        '{"fleet": "lab", "arms": {"a1": {"gripper_closed_deg": 5, "gripper_open_deg": 5}}}',
        '{"fleet": "lab", "arms": {}, "extra": 1}',
        "[" * 5000,
        "not json",
    ],
)
def test_a_hostile_layout_record_is_refused_with_the_file_named(text: str) -> None:
    with pytest.raises(RecordError, match="x.mcap"):
        layout_from_metadata("x.mcap", {"json": text})


def test_the_event_log_keeps_transitions_and_is_bounded() -> None:
    fleet = ViewerFleet(("a1",), "lab")
    ok = m.ArmStatus(stamp_ns=1, link="ok")
    stopped = m.ArmStatus(stamp_ns=1, link="ok", estopped=True, stop_reason="watchdog")
    for status in (ok, ok, stopped, stopped, stopped, ok):
        fleet.ingest(SPACE.arm("a1", keys.STATUS), encode(status))
    diag = m.Diag(1, "ok", 10, 0, 0, 0, 0, 3, 0, 10.0, 0.1)
    refused = m.Diag(1, "ok", 20, 0, 0, 0, 2, 5, 0, 10.0, 0.1, last_error="4002 stopped")
    fleet.ingest(SPACE.arm("a1", keys.DIAG), encode(diag))
    fleet.ingest(SPACE.arm("a1", keys.DIAG), encode(refused))
    fleet.ingest(SPACE.arm("a9", keys.STATUS), encode(stopped))  # not an inventory arm
    fleet.ingest(SPACE.arm("a1", keys.STATUS), b"{not json")
    assert fleet.malformed == 1
    newest = [(e.kind, e.text) for e in fleet.events.newest()]
    assert newest == [
        ("refused", "refused 2 commands: 4002 stopped"),
        ("released", "stop released by a reset"),
        ("stop", "STOPPED (latched): watchdog"),
    ]
    # A flood of distinct stop requests cannot grow the log.
    for k in range(MAX_EVENTS * 3):
        stop = m.StopRequest(stamp_ns=1, source="x", stop_id=f"id{k}", reason="y" * 900)
        fleet.ingest(SPACE.estop, encode(stop))
    assert len(fleet.events.newest(10_000)) == MAX_EVENTS
    assert all(len(e.text) <= 300 for e in fleet.events.newest())
    assert "<script>" not in EventLog().html()
    log = EventLog()
    log.add("stop", "a1", "<script>alert(1)</script>")
    assert "<script>" not in log.html() and "&lt;script&gt;" in log.html()


def test_each_stop_gets_one_timing_entry_once_every_arm_is_still() -> None:
    fleet = ViewerFleet(("a1", "a2"), "lab")

    def report(stills: tuple[float | None, float | None]) -> bytes:
        arms = {
            arm: m.StopTiming(received_ms=received, dds_written_ms=received + 1, still_ms=still)
            for arm, received, still in zip(("a1", "a2"), (84.0, 91.0), stills)
        }
        return encode(m.StopReport(stop_id="s1", source="cli@pc", stamp_ns=1, arms=arms))

    for stills in ((None, None), (402.0, None), (402.0, 517.0), (402.0, 517.0)):
        fleet.ingest(SPACE.stop_report, report(stills))  # the coordinator's, on every ack
    fleet.ingest(SPACE.stop_report, b'{"stop_id": 7}')
    texts = [e.text for e in fleet.events.newest()]
    assert texts == [
        "stop by cli@pc: 2 arms still within 517 ms of the put (slowest a2), received within 91 ms"
    ]
    assert fleet.malformed == 1


def test_a_confirmation_holds_for_its_own_target_only() -> None:
    confirmations = Confirmations()
    nonce = confirmations.request(7, "a1")
    assert not confirmations.confirm(7, nonce, FLEET)  # a1's dialog cannot reset the fleet
    nonce = confirmations.request(7, "a1")
    assert not confirmations.confirm(7, nonce.replace("a1:", "a2:"), "a2")
    nonce = confirmations.request(7, "a1")
    assert confirmations.confirm(7, nonce, "a1")
    assert not confirmations.confirm(7, nonce, "a1")  # once


@pytest.mark.parametrize("aspect", [0.7, 1.0, 1.6, 2.4])
@pytest.mark.parametrize("width", [700.0, 1280.0, 2560.0])
def test_the_fit_frames_every_point_in_the_part_the_panel_leaves_free(
    aspect: float, width: float
) -> None:
    rng = np.random.default_rng(int(aspect * 10 + width))
    fov = np.deg2rad(45.0)
    for _ in range(20):
        points = rng.uniform([-2, -3, 0], [2, 3, 0.8], (50, 3)) * rng.uniform(0.05, 3.0)
        right_edge = usable_right_edge(width)
        position, look_at = fit_view(points, fov, aspect, right_edge)
        back, right, up = camera_axes(position - look_at, UP)
        rel = points - position
        depth = -(rel @ back)
        x = (rel @ right) / depth / (np.tan(fov / 2) * aspect)
        y = (rel @ up) / depth / np.tan(fov / 2)
        assert np.all(depth > 0)
        assert x.min() >= -1 - 1e-9 and x.max() <= right_edge + 1e-9 and np.abs(y).max() <= 1
        # Tight: along the binding axis the points reach the margin on both sides.
        span_x = (x.max() - x.min()) / (1 + right_edge)
        span_y = (y.max() - y.min()) / 2
        near = depth.min() <= 0.5 + 1e-6  # or the camera is as close as it may come
        assert near or max(span_x, span_y) > 0.85, (span_x, span_y)
