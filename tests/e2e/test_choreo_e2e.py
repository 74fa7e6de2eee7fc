"""Choreography, mirror and recording end to end on three simulated arms (real router, DDS
simulator, one agent per arm; the player, mirror and recorder run in this process on real Zenoh).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import msgspec
import pytest
from mcap.reader import make_reader

from fleet.api import Fleet
from fleet.choreo.player import Player
from fleet.choreo.script import parse_script
from fleet.client import FleetClient
from fleet.record.reader import read_recording
from fleet.record.recorder import Recorder
from fleet.record.replay import recorded_joints, teach_script
from fleet.teleop.mapping import parse_mappings
from fleet.teleop.mirror import Mirror
from fleet.wire import messages as m
from fleet.wire import payloads
from testkit.harness import FleetHarness, wait_until
from testkit.load import xfail_if_overloaded

ARMS = ("a1", "a2", "a3")
SCRIPT = """
[choreo]
name = "e2e"
tolerance_deg = 10.0

[[step]]
duration_s = 1.5
all = [0, -30, 40, 0, 30, 0, 30]
a2 = [20, -40, 50, 0, 20, 10, 40]

[[step]]
wait = "reached"
timeout_s = 3.0

[[step]]
duration_s = 1.5
all = [-20, -20, 30, 0, 40, -10, 20]

[[step]]
duration_s = 1.5
all = [0, 0, 0, 0, 0, 0, 10]
"""


def start_three(h: FleetHarness) -> FleetClient:
    h.start_router()
    h.start_sim()
    for arm in ARMS:
        h.start_agent(arm, name=f"agent-{arm}")
    client = h.client()
    wait_until(lambda: h.all_links_ok(client), 30.0)
    return client


def _angles(client: FleetClient) -> dict[str, list[float]]:
    return {a: j.angles_deg for a, (_s, j) in client.snapshot().items() if j is not None}


@pytest.mark.timing
def test_script_completes_with_every_keyframe_within_tolerance(
    fleet3_harness: FleetHarness,
) -> None:
    client = start_three(fleet3_harness)
    script = parse_script(SCRIPT, "e2e.toml", list(ARMS))
    frames: list[str] = []
    result = Player(client, script, on_progress=lambda f: frames.append(f.label)).play()
    assert result.ok, result.reason
    assert len(result.keyframe_error_deg) == 3
    assert max(result.keyframe_error_deg) < 5.0, result
    assert {"step 0", "step 2", "step 3"} <= set(frames)
    # loose: other test runs share these 2 cores; typical is 0.5-1 ms (docs/results)
    assert result.start_skew_ms is not None
    xfail_if_overloaded(
        [f"start skew {result.start_skew_ms} ms"] if result.start_skew_ms >= 60 else []
    )
    assert result.start_skew_ms < 60.0
    final = _angles(client)
    for arm in ARMS:
        assert max(abs(a - b) for a, b in zip(final[arm], [0, 0, 0, 0, 0, 0, 10])) < 1.0
    print(f"skew {result.start_skew_ms} ms, keyframe errors {result.keyframe_error_deg} deg")
    # The scripting API: the player released the arms, a Fleet can move one and read state.
    with Fleet(fleet3_harness.inventory) as fleet:
        assert fleet.wait_for_arms(5.0)
        reply = fleet.arms["a1"].move(angles_deg=[10, -10, 10, 0, 10, 0, 20], wait=True)
        assert reply.ok and reply.reached
        # The reply (a query's answer) may overtake the joints sample that showed the reach
        # (a publication): the Fleet sees the pose within a feedback period or two.
        a1 = fleet.arms["a1"]
        wait_until(lambda: abs((a1.joints() or [99.0])[0] - 10.0) < 2.0, 1.0)
        replies = fleet.group("all").move(angles_deg=[0.0] * 7, wait=True)
        assert all(r.reached for r in replies.values())
    assert client.command("a1", m.MoveJoints(angles_deg=[0.0] * 7)).ok  # released on close


def test_stop_mid_script_halts_every_arm_and_says_why(fleet3_harness: FleetHarness) -> None:
    client = start_three(fleet3_harness)
    script = parse_script(SCRIPT, "e2e.toml", list(ARMS))
    player = Player(client, script)
    results: list[object] = []
    thread = threading.Thread(target=lambda: results.append(player.play()), name="player")
    thread.start()
    time.sleep(2.5)  # mid-script
    acks = client.estop("a2", reason="test stop")
    assert acks["a2"] is not None
    thread.join(timeout=15.0)
    result = results[0]
    assert not result.ok and "'a2' is stopped" in result.reason, result  # type: ignore[attr-defined]
    first = _angles(client)
    time.sleep(0.6)
    after = _angles(client)
    for arm in ARMS:
        assert max(abs(a - b) for a, b in zip(first[arm], after[arm])) < 0.5, f"{arm} moves"
    # The others were held, not stopped by the watchdog: they take commands again.
    assert client.command("a1", m.MoveJoints(angles_deg=[0.0] * 7)).ok


@pytest.mark.timing
def test_mirror_follows_a_dragged_leader(fleet3_harness: FleetHarness) -> None:
    client = start_three(fleet3_harness)
    mirror = Mirror(client, "a1", parse_mappings(["a2", "a3"], ["a3:0"]))
    stop = threading.Event()
    results: list[object] = []
    thread = threading.Thread(target=lambda: results.append(mirror.run(stop)), name="mirror")
    thread.start()
    wait_until(lambda: mirror.result.samples > 5, 10.0)
    mirror.result.latencies_ms.clear()  # measure the streaming of the drag only
    fault_key = client.keys.arm("a1", "sim/fault")
    for joint, angle in ((0, 40.0), (1, -30.0)):
        payload = msgspec.json.encode(
            {"op": "drag", "joint": joint, "angle_deg": angle, "speed_deg_s": 60.0}
        )
        assert list(client.session.get(fault_key, payload=payload, timeout=3.0))
    wait_until(lambda: abs(_angles(client)["a1"][0] - 40.0) < 0.5, 5.0)

    def followed() -> bool:
        angles = _angles(client)
        return abs(angles["a2"][0] - 40.0) < 2.0 and abs(angles["a3"][0] + 40.0) < 2.0

    wait_until(followed, 5.0)
    assert abs(_angles(client)["a2"][1] + 30.0) < 2.0
    stop.set()
    thread.join(timeout=10.0)
    result = results[0]
    reason = str(getattr(result, "reason", ""))
    # A follower's feedback 0.35 s late makes its link stale and the mirror stop, as it must;
    # on an overloaded host that measures the scheduler (the simulator starved).
    xfail_if_overloaded([f"the mirror stopped: {reason}"] if "link stale" in reason else [])
    assert result.ok and result.latencies_ms, result  # type: ignore[attr-defined]
    print(result.summary())  # type: ignore[attr-defined]
    median_ms = sorted(result.latencies_ms)[len(result.latencies_ms) // 2]  # type: ignore[attr-defined]
    xfail_if_overloaded([f"median latency {median_ms:.0f} ms"] if median_ms >= 50.0 else [])
    assert median_ms < 50.0


@pytest.mark.timing
def test_recording_replays_the_same_trajectory(
    fleet3_harness: FleetHarness, tmp_path: Path
) -> None:
    client = start_three(fleet3_harness)
    path = tmp_path / "teach.mcap"
    poses = ([30, -30, 40, 0, 20, 10, 30], [-20, -10, 20, 10, 30, 0, 10], [0.0] * 7)
    with Recorder(client.session, client.keys, ["a1"], path) as recorder:
        for pose in poses:
            assert client.command("a1", m.MoveJoints(angles_deg=list(pose), wait_reached=True)).ok
    assert recorder.counts[client.keys.arm("a1", "joints")] > 20
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic for c in summary.channels.values()}
        schemas = {s.name: s.encoding for s in summary.schemas.values()}
    assert client.keys.arm("a1", "raw/command") in topics and schemas["Joints"] == "jsonschema"

    recording = read_recording(path)
    assert recording.complete, recording.describe()
    source, samples = recorded_joints(recording.messages)
    assert source == "a1"
    start = tuple(_angles(client)["a2"])
    script = teach_script(samples, "a2", start, str(path))
    seen: list[m.Joints] = []
    sub = client.session.declare_subscriber(
        client.keys.arm("a2", "joints"),
        lambda s: seen.append(payloads.JOINTS.decode(s.payload.to_bytes())),
    )
    result = Player(client, script).play()
    sub.undeclare()
    assert result.ok, result.reason
    recorded = [tuple(s.angles_deg) for s in samples]
    replayed = [tuple(s.angles_deg) for s in seen]

    # Every replayed sample after the approach lies near the recorded path, and vice versa.
    def gap(p: tuple[float, ...], path_: list[tuple[float, ...]]) -> float:
        return min(max(abs(a - b) for a, b in zip(p, q)) for q in path_)

    tail = replayed[len(replayed) // 3 :]
    off = (
        max(gap(p, recorded) for p in tail),
        max(gap(p, replayed) for p in recorded[len(recorded) // 3 :]),
    )
    # The arm ends where the recording ended, once its servo settled (the last sample may be
    # taken while it still converges on a loaded host).
    settled = wait_until(
        lambda: (now := tuple(_angles(client)["a2"])) and gap(recorded[-1], [now]) < 1.5 and now,
        10.0,  # a bound for the state, not a goal: 3 s failed on a loaded host
    )
    assert gap(recorded[-1], [settled]) < 1.5
    # The path last: streamed targets late on an overloaded host cut its corners (8.15 deg
    # at load 5-10 in a fresh-clone run; within 6 on a quiet one).
    xfail_if_overloaded(
        [f"replayed path {off[0]:.1f} / {off[1]:.1f} deg off"] if max(off) >= 6.0 else []
    )
    assert max(off) < 6.0, off
