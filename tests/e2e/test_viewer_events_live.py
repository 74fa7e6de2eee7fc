"""The live viewer's subscriptions (viewer/state.py on a real router): stops and resets of a
gripper and a G1, and a choreography's end, reach its event log from the key space."""

from __future__ import annotations

from fleet.dex1.kind import KIND as GRIPPER_KIND
from fleet.g1.kind import KIND as G1_KIND
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode
from fleet.wire.session import open_client
from testkit.harness import FleetHarness, wait_until
from viewer.state import ViewerFleet


def test_device_stops_resets_and_a_dance_end_reach_the_event_log(
    fleet_harness: FleetHarness,
) -> None:
    h = fleet_harness
    h.start_router()
    space = keys.KeySpace(h.inventory.fleet)
    devices = {"gl": (GRIPPER_KIND, "a1"), "h1": (G1_KIND, "")}
    with (
        open_client([h.endpoint]) as viewer_session,
        open_client([h.endpoint]) as operator,
        ViewerFleet(("a1",), h.inventory.fleet, viewer_session, devices=devices) as viewer,
    ):
        puts = [
            (space.device(keys.GRIPPER, "gl", keys.ESTOP), m.StopRequest(1, "cli", "s1", "why")),
            (space.device(keys.G1, "h1", keys.RESET), m.ResetRequest(1, "op")),
            (
                space.choreo_of("operator"),
                m.ChoreoStatus(1, "p1", "demo wave", "aborted", "arm 'a1' is stopped", 0, "ready"),
            ),
        ]
        expected = {
            ("stop", "gl", "stop requested by cli: why"),
            ("reset", "h1", "reset requested by op"),
            (
                "dance stopped",
                None,
                "'demo wave' STOPPED: arm 'a1' is stopped (pass 1, step 'ready')",
            ),
        }

        def logged() -> bool:
            for key, payload in puts:  # until the subscriptions are matched: latest wins
                operator.put(key, encode(payload))
            events = {(e.kind, e.arm, e.text) for e in viewer.events.newest()}
            return expected <= events

        wait_until(logged, 10.0)
