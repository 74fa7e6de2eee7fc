"""The G1 in Foxglove: the live bridge publishes its URDF and its joints as transforms, posed
from the simulated G1's relayed lowstate (stamped with it), next to its state channel (FSM,
stop latch); ``fleet record`` writes the same 3D channels into the file. Real processes: a
router, ``fleet sim`` (a1, gl, h1), the agent, ``fleet foxglove``, ``fleet record``."""

from __future__ import annotations

import socket
import statistics
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from fleet.g1.kind import KIND as G1
from fleet.g1.messages import ArmTarget, G1LowState
from fleet.record.layout import layout_of
from fleet.scene3d.frames3d import G1Frames, transforms_topic, urdf_topic
from fleet.web.access import FOXGLOVE_TOKEN_ENV as TOKEN_ENV
from fleet.wire import keys
from testkit.collect import Collector
from testkit.foxglove_client import FoxgloveClient, protobuf_class, stamp_ns_of, world_from_links
from testkit.harness import FleetHarness, free_port, wait_until
from testkit.kinds import devices_fleet

TOKEN = "test-token-g1-0123456789abcdef"
LOW = G1.payloads[keys.LOWSTATE]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FleetHarness]:
    with devices_fleet(tmp_path_factory.mktemp("foxg1")) as harness:
        yield harness


def assert_pose(frames: G1Frames, low: G1LowState, message: Any) -> None:
    """Foxglove's composed frames are where the viewer draws every link (g1_body.py)."""
    expected = frames.link_matrices("h1", low)
    got = world_from_links(message)
    assert len(message.transforms) == len(frames.body.model.links)
    for i, link in enumerate(frames.body.model.links):
        np.testing.assert_allclose(got[f"h1/{link}"], expected[i], atol=1e-6, rtol=0)


def _listening(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def _raise_left_arm(client: Any, lows: Collector[G1LowState], *steps: float) -> None:
    """The left shoulder pitch (motor 15) through rt/arm_sdk, in steps the agent allows (each
    within 0.6 rad of the measured pose: waited for in the relayed lowstate)."""
    for value in steps:
        q = [0.0] * 17
        q[3] = value
        reply = client.device_command("h1", ArmTarget(q_rad=q, speed_rad_s=1.5))
        assert reply.ok, reply
        wait_until(lambda v=value: abs(lows.latest().q_rad[15] - v) < 0.05, 15.0)  # type: ignore[union-attr]


def test_the_g1_is_posed_live_in_foxglove(
    fleet: FleetHarness, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    client = fleet.client()
    space = keys.KeySpace(fleet.inventory.fleet)
    low_key, state_key = space.device("g1", "h1", keys.LOWSTATE), space.device("g1", "h1", "state")
    lows: Collector[G1LowState] = Collector(client.session, low_key, LOW.decode)
    wait_until(lambda: lows.latest() is not None, 30.0)
    port = free_port()
    fleet.start("foxglove", ["-m", "fleet.cli.main", "foxglove", "--port", str(port)])
    wait_until(lambda: _listening(port), 20.0)
    frames = G1Frames.load(layout_of(fleet.inventory))
    fox = FoxgloveClient(f"ws://127.0.0.1:{port}/?token={TOKEN}")
    pool = ThreadPoolExecutor(1)
    try:
        wanted = {transforms_topic("h1"), urdf_topic("h1"), low_key, state_key}
        topics = fox.wait_for_topics(wanted | {transforms_topic("a1")}, 20.0)
        assert topics[transforms_topic("h1")]["schemaName"] == "foxglove.FrameTransforms"
        assert "G1State" in topics[state_key]["schema"]
        fox.subscribe(*sorted(wanted))
        # Moved from another thread: this one reads all the while, so arrival times are the
        # stream's, not a backlog's.
        raising = pool.submit(_raise_left_arm, client, lows, -0.5, -1.0)
        recorded: dict[int, G1LowState] = {}
        arrived: list[tuple[int, Any]] = []  # (arrival ns, transforms), checked after the stream
        urdf, state = None, None
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            got = fox.read(5.0)
            assert got is not None, "no message within 5 s"
            arrived_ns = time.time_ns()
            channel_id, _log_time, payload = got
            topic = fox.channels[channel_id]["topic"]
            message = fox.decode(channel_id, payload)
            if topic == low_key:
                low = LOW.decode(payload)
                recorded[low.stamp_ns] = low
            elif topic == urdf_topic("h1"):
                urdf = message["data"]
            elif topic == state_key:
                state = message
            else:
                arrived.append((arrived_ns, message))
                posed = recorded.get(stamp_ns_of(message))
                up = posed is not None and posed.q_rad[15] < -0.95
                if up and urdf is not None and state is not None:
                    break
        raising.result(timeout=30.0)
        assert urdf is not None and '<link name="h1/pelvis"' in urdf
        assert state is not None and state["fsm_id"] == 500 and state["fsm_name"] == "walk"
        matched: list[float] = []  # the left shoulder pitch of each checked transform
        latency_ms: list[float] = []
        for arrived_ns, message in arrived:
            low = recorded.get(stamp_ns_of(message))
            if low is None:
                continue  # its lowstate came before the subscription, or after the end
            assert_pose(frames, low, message)
            matched.append(low.q_rad[15])
            latency_ms.append((arrived_ns - low.stamp_ns) / 1e6)
        assert len(matched) >= 5 and min(matched) < -0.9, matched  # followed the arm up
        assert max(matched) - min(matched) > 0.8, matched  # ... from where it was
        print(
            f"\nG1 transforms checked against FK: {len(matched)} of {len(arrived)}; lowstate "
            f"stamp -> Foxglove client: median {statistics.median(latency_ms):.1f} ms, "
            f"max {max(latency_ms):.1f} ms"
        )
        # The stop latch shows on the G1's state channel, as an arm's on its status.
        client.estop(reason="foxglove g1 test")
        stopped = False
        deadline = time.monotonic() + 15.0
        while not stopped and time.monotonic() < deadline:
            got = fox.read(5.0)
            if got is not None and fox.channels[got[0]]["topic"] == state_key:
                stopped = bool(fox.decode(got[0], got[2])["estopped"])
        assert stopped, "the G1's state never showed the stop"
    finally:
        pool.shutdown()
        fox.close()
        fleet.stop("foxglove")
        client.reset()
        lows.close()


@pytest.mark.timing
def test_a_recording_holds_the_g1_in_3d(fleet: FleetHarness, tmp_path: Path) -> None:
    client = fleet.client()
    out = tmp_path / "g1.mcap"
    wait_until(lambda: fleet.all_links_ok(client), 30.0)
    argv = ["-m", "fleet.cli.main", "record", "-o", str(out), "--for-s", "3"]
    record = fleet.start("record", argv)
    space = keys.KeySpace(fleet.inventory.fleet)
    lows: Collector[G1LowState] = Collector(
        client.session, space.device("g1", "h1", keys.LOWSTATE), LOW.decode
    )
    try:
        wait_until(lambda: "recording" in fleet.log("record"), 20.0)
        _raise_left_arm(client, lows, -0.5)
        assert record.wait(timeout=30) == 0, fleet.log("record")
    finally:
        lows.close()
    frames = G1Frames.load(layout_of(fleet.inventory))
    lowstates: dict[int, G1LowState] = {}
    transforms: list[Any] = []
    urdfs: list[bytes] = []
    with open(out, "rb") as stream:
        reader = make_reader(stream)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.topic == space.device("g1", "h1", keys.LOWSTATE):
                low = LOW.decode(message.data)
                lowstates[low.stamp_ns] = low
            elif channel.topic == transforms_topic("h1"):
                assert schema is not None
                transforms.append(protobuf_class(schema.name, schema.data).FromString(message.data))
            elif channel.topic == urdf_topic("h1"):
                urdfs.append(message.data)
        attachments = {a.name for a in reader.iter_attachments()}
    assert urdfs and b"h1/pelvis" in urdfs[0]
    assert {"d1_550.urdf", "g1_29dof.urdf"} <= attachments
    assert len(transforms) >= 15, len(transforms)  # 10 Hz for 3 s
    for message in transforms:  # one per recorded lowstate, each its pose
        assert_pose(frames, lowstates[stamp_ns_of(message)], message)
    assert len(transforms) == len(lowstates)
