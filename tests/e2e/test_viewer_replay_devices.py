"""``fleet viewer --replay`` draws every kind: a recording made by ``fleet record`` from the
simulators (a1, its gripper gl, the G1 h1) is shown on a real viser server with the gripper's
opening on a1's fingers and the G1 posed from its recorded lowstate, its FSM and stop on its
label, through the live viewer's own scene code; scrubbing back draws it as it was. Real
processes: a router, ``fleet sim``, the agent, ``fleet record``."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.dex1.kind import KIND as GRIPPER
from fleet.dex1.messages import GripperMove
from fleet.g1.kind import KIND as G1
from fleet.g1.messages import ArmTarget, G1LowState
from fleet.record.reader import read_recording
from fleet.wire import keys
from testkit.collect import Collector
from testkit.harness import free_port, wait_until
from testkit.kinds import devices_fleet
from testkit.recordings import write_recording
from viewer.app import Viewer
from viewer.replay import replay_source


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """4-6 s of the simulators: the gripper opened to 80 %, the G1's left shoulder raised to
    -0.5 rad through rt/arm_sdk, then a fleet stop; recorded by ``fleet record``."""
    tmp = tmp_path_factory.mktemp("replaydev")
    path = tmp / "devices.mcap"
    with devices_fleet(tmp) as fleet:
        client = fleet.client()
        space = keys.KeySpace(fleet.inventory.fleet)
        lows: Collector[G1LowState] = Collector(
            client.session, space.device("g1", "h1", keys.LOWSTATE), G1.payloads["lowstate"].decode
        )
        try:
            wait_until(lambda: lows.latest() is not None and fleet.all_links_ok(client), 40.0)
            wait_until(lambda: all(s is not None for s in client.device_snapshot().values()), 30.0)
            argv = ["-m", "fleet.cli.main", "record", "-o", str(path), "--for-s", "6"]
            record = fleet.start("record", argv)
            wait_until(lambda: "recording" in fleet.log("record"), 20.0)
            assert client.device_command("gl", GripperMove(open_pct=80.0)).ok
            q = [0.0] * 17
            q[3] = -0.5
            assert client.device_command("h1", ArmTarget(q_rad=q, speed_rad_s=1.5)).ok
            wait_until(lambda: abs(lows.latest().q_rad[15] + 0.5) < 0.05, 15.0)  # type: ignore[union-attr]
            state = client.device_snapshot
            wait_until(lambda: abs(state()["gripper/gl"].opening_pct - 80.0) < 3.0, 15.0)
            client.estop(reason="replay test")
            wait_until(lambda: state()["g1/h1"].estopped, 10.0)
            assert record.wait(timeout=30) == 0, fleet.log("record")
            client.reset()
        finally:
            lows.close()
    return path


def test_the_replay_viewer_draws_the_gripper_and_the_g1(recording: Path) -> None:
    source = replay_source(read_recording(recording))
    assert source.layout.devices["gl"].mount == "a1" and source.layout.devices["h1"].kind == "g1"
    lows = [r for r in source.messages if r.key.endswith("/g1/h1/lowstate")]
    grips = [r for r in source.messages if r.key.endswith("/gripper/gl/state")]
    assert len(lows) >= 40 and len(grips) >= 100, (len(lows), len(grips))
    with Viewer(replay=source, port=free_port()) as viewer:  # a real viser server
        timeline, g1, arms = viewer.timeline, viewer.g1_scene, viewer.scene
        assert timeline is not None and g1 is not None and g1.devices == ("h1",)
        assert set(viewer.panels.device_panels) == {"gl", "h1"}  # state lines, no controls
        assert not any(p.sliders or p.buttons for p in viewer.panels.device_panels.values())
        closed, fully_open = arms.gripper_deg[0]
        decode = G1.payloads[keys.LOWSTATE].decode
        poses = [(r.log_time_ns, decode(r.data).q_rad[15]) for r in lows]
        raised_ns, raised_q = min(poses, key=lambda p: p[1])
        assert raised_q < -0.45  # the arm was up at some point of the file

        def seek(log_time_ns: int) -> None:
            timeline.request_seek((log_time_ns - timeline.start_ns) / 1e9)

        seek(raised_ns)  # where the arm was highest: drawn at that very sample
        wait_until(lambda: abs(g1._q[0, 15] - raised_q) < 1e-9, 10.0)
        timeline.request_seek(timeline.duration_s)  # the end: stopped (the arms held)
        wait_until(lambda: g1._text[0].endswith("STOPPED"), 10.0)
        assert g1._text[0].startswith("h1 · fsm 500 walk")
        wait_until(lambda: abs(g1._q[0, 15] - poses[-1][1]) < 0.003, 10.0)  # in the deadband
        opening = (arms._drawn_deg[0, 6] - closed) / (fully_open - closed)
        assert abs(opening - 0.8) < 0.04, opening  # gl's opening on a1's fingers
        assert timeline.state.malformed == 0
        fed_at_end = timeline._fed
        # Back to before anything moved, once both robots had a sample (the G1's first may come
        # after the gripper's: before it the G1 has nothing to be drawn from): rebuilt, redrawn.
        # (The stop held the G1's arms raised to the end of the file.)
        early_ns = max(grips[0].log_time_ns, lows[0].log_time_ns) + 1_000_000
        seek(early_ns)
        wait_until(lambda: abs(g1._q[0, 15]) < 0.05 and "STOPPED" not in g1._text[0], 10.0)
        then = [g for g in grips if g.log_time_ns <= early_ns][-1]
        first = GRIPPER.payloads[keys.STATE].decode(then.data).opening_pct / 100.0
        assert abs(first - 0.8) > 0.1  # the gripper moved during the file

        def drawn() -> float:
            return float((arms._drawn_deg[0, 6] - closed) / (fully_open - closed))

        wait_until(lambda: abs(drawn() - first) < 0.02, 10.0)  # drawn as it was then
        print(
            f"\nreplayed {fed_at_end} of {len(source.messages)} samples shown ({len(lows)} G1 "
            f"lowstates, {len(grips)} gripper states) over {timeline.duration_s:.1f} s"
        )
        assert not viewer.failed.is_set()


def test_a_malformed_recorded_lowstate_is_counted_and_shown_never_drawn(tmp_path: Path) -> None:
    path = tmp_path / "damaged.mcap"
    write_recording(path, devices=True)  # one lowstate of 28 joints among 51 good ones
    with Viewer(replay=replay_source(read_recording(path)), port=free_port()) as viewer:
        timeline, g1, panels = viewer.timeline, viewer.g1_scene, viewer.panels
        assert timeline is not None and g1 is not None and panels.replay is not None
        timeline.request_seek(timeline.duration_s)
        # The last good pose, and the label of the last state (drawn in the same frame or the
        # next: one was seen before the other on a loaded host).
        wait_until(lambda: abs(g1._q[0, 15] + 1.0) < 1e-9 and g1._text[0].endswith("STOPPED"), 10.0)
        wait_until(lambda: "1 recorded samples did not decode" in panels.replay.where.content, 5.0)  # type: ignore[union-attr]
        assert timeline.state.malformed == 1 and not viewer.failed.is_set()
