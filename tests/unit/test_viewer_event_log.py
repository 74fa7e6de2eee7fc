"""The viewer's event log for every kind of unit: stops and resets of the grippers and the G1s
appear as the arms' do (requested, latched, released); a choreography that stops is an event
and a visible status, with the reason."""

from __future__ import annotations

import html

import msgspec

from fleet.choreo.announce import SILENT_S
from fleet.dex1.kind import KIND as GRIPPER_KIND
from fleet.g1.kind import KIND as G1_KIND
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode
from testkit.samples import GRIP_STATE, g1_state
from viewer.dance import dance_html
from viewer.state import ViewerFleet

SPACE = keys.KeySpace("lab")


def _fleet() -> ViewerFleet:
    devices = {"gl": (GRIPPER_KIND, "a1"), "h1": (G1_KIND, "")}
    return ViewerFleet(("a1",), "lab", devices=devices)


def _events(fleet: ViewerFleet) -> list[tuple[str, str | None, str]]:
    return [(e.kind, e.arm, e.text) for e in reversed(fleet.events.newest())]


def test_device_and_arm_stop_and_reset_requests_are_logged_once_each() -> None:
    fleet = _fleet()
    for kind, unit in ((keys.GRIPPER, "gl"), (keys.G1, "h1")):
        stop = m.StopRequest(stamp_ns=1, source="cli@pc", stop_id=f"s-{unit}", reason="test")
        for _repeat in range(3):  # a stop is repeated until acknowledged: one entry
            fleet.ingest(SPACE.device(kind, unit, keys.ESTOP), encode(stop))
        reset = m.ResetRequest(stamp_ns=2, source="op@pc")
        fleet.ingest(SPACE.device(kind, unit, keys.RESET), encode(reset))
    arm_stop = m.StopRequest(stamp_ns=1, source="viewer", stop_id="s-a1")
    fleet.ingest(SPACE.arm("a1", keys.ESTOP), encode(arm_stop))
    fleet.ingest(SPACE.arm("a1", keys.RESET), encode(m.ResetRequest(stamp_ns=2, source="op")))
    fleet.ingest(SPACE.device(keys.G1, "h9", keys.ESTOP), encode(arm_stop))  # not ours
    fleet.ingest(SPACE.device(keys.GRIPPER, "gl", keys.RESET), b"{")
    assert fleet.malformed == 1
    assert _events(fleet) == [
        ("stop", "gl", "stop requested by cli@pc: test"),
        ("reset", "gl", "reset requested by op@pc"),
        ("stop", "h1", "stop requested by cli@pc: test"),
        ("reset", "h1", "reset requested by op@pc"),
        ("stop", "a1", "stop requested by viewer: no reason given"),
        ("reset", "a1", "reset requested by op"),
    ]


def test_a_device_latching_and_releasing_its_stop_is_one_event_each() -> None:
    fleet = _fleet()
    grip_stopped = msgspec.structs.replace(GRIP_STATE, estopped=True, stop_reason="watchdog")
    for state in (GRIP_STATE, grip_stopped, grip_stopped, GRIP_STATE, GRIP_STATE):
        fleet.ingest(SPACE.device(keys.GRIPPER, "gl", keys.STATE), encode(state))
    g1 = g1_state("sport", "sport", True)
    g1_stopped = msgspec.structs.replace(g1, estopped=True, stop_reason="operator")
    for state in (g1, g1_stopped, g1_stopped, g1):
        fleet.ingest(SPACE.device(keys.G1, "h1", keys.STATE), encode(state))
    assert _events(fleet) == [
        ("stop", "gl", "STOPPED (latched): watchdog"),
        ("released", "gl", "stop released by a reset"),
        ("stop", "h1", "STOPPED (latched): operator"),
        ("released", "h1", "stop released by a reset"),
    ]


def _dance(state: str, step: str = "ripple", reason: str = "", player: str = "p1") -> bytes:
    status = m.ChoreoStatus(1, player, "demo wave", state, reason, 2, step)  # type: ignore[arg-type]
    return encode(status)


def test_a_dance_that_stops_is_an_event_and_a_red_status_with_the_reason() -> None:
    fleet = _fleet()
    key = SPACE.choreo_of("operator")
    for state in ("playing", "playing", "playing"):  # repeated at 1 Hz: one event
        fleet.ingest(key, _dance(state), at_s=1.0)
    why = "arm 'a1' is stopped (watchdog)"
    fleet.ingest(key, _dance("aborted", reason=why), at_s=2.0)
    fleet.ingest(key, _dance("completed", player="p2"), at_s=3.0)
    fleet.ingest(SPACE.choreo_of("operator"), b"{", at_s=3.0)
    assert fleet.malformed == 1
    assert _events(fleet) == [
        ("dance", None, "'demo wave' playing (operator, pass 3, step 'ripple')"),
        ("dance stopped", None, f"'demo wave' STOPPED: {why} (pass 3, step 'ripple')"),
        ("dance", None, "'demo wave' completed"),
    ]
    views = fleet.snapshot().dances
    assert [(v.player, v.state) for v in views] == [("p2", "completed"), ("p1", "aborted")]
    page = dance_html(views)
    assert "data-dance-state='aborted'" in page and "STOPPED at" in page
    assert html.escape(why) in page


def test_a_dance_whose_player_falls_silent_is_shown_stopped_once() -> None:
    clock = [10.0]
    fleet = ViewerFleet(("a1",), "lab", clock=lambda: clock[0])
    fleet.ingest(SPACE.choreo_of("operator"), _dance("playing"), at_s=10.0)
    clock[0] = 10.0 + SILENT_S - 0.1
    assert [v.state for v in fleet.snapshot().dances] == ["playing"]
    clock[0] = 10.0 + SILENT_S + 0.1
    for _tick in range(3):  # the render thread takes a snapshot at 20 Hz: one event
        assert [v.state for v in fleet.snapshot().dances] == ["silent"]
    stopped = [e.text for e in fleet.events.newest() if e.kind == "dance stopped"]
    assert stopped == [
        "'demo wave' STOPPED: its player fell silent (no state for 3 s: killed, or its host hangs)"
    ]
