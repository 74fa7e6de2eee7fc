"""Foxglove (issue 16): the live bridge seen by a client speaking Foxglove's WebSocket protocol,
and the 3D channels of a recording decoded with the mcap reader and Foxglove's schemas."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from foxglove.messages import FrameTransforms
from mcap.reader import make_reader

from fleet.record.layout import layout_of
from fleet.record.reader import read_recording
from fleet.record.replay import recorded_joints
from fleet.scene3d.frames3d import ArmFrames, transforms_topic, urdf_topic
from fleet.scene3d.kinematics import matrix_to_wxyz
from fleet.web.access import FOXGLOVE_TOKEN_ENV as TOKEN_ENV
from fleet.wire import messages as m
from testkit.foxglove_client import FoxgloveClient, protobuf_class, world_from_links
from testkit.harness import FleetHarness, free_port, wait_until
from testkit.samples import GRIP_STATE
from viewer.replay import replay_source


def assert_matches_fk(frames: ArmFrames, arm: str, angles: list[float], message: Any) -> None:
    expected = frames.link_matrices(arm, angles)
    got = world_from_links(message)
    assert len(message.transforms) == len(frames.model.links)
    for i, link in enumerate(frames.model.links):
        np.testing.assert_allclose(got[f"{arm}/{link}"], expected[i], atol=1e-6, rtol=0)


def test_transforms_pure() -> None:
    """The message is FK: a rotated, displaced base and a bent arm, composed back exactly."""
    from fleet.record.layout import ArmPlacement, FleetLayout

    placement = ArmPlacement(base_xyz=(1.0, -0.5, 0.2), base_rpy_deg=(10.0, -20.0, 135.0))
    frames = ArmFrames.load(FleetLayout("lab", {"a1": placement}))
    angles = [30.0, -45.0, 60.0, 90.0, -30.0, 120.0, 40.0]
    # Foxglove's own encoding, decoded with Foxglove's own schema.
    cls = protobuf_class("foxglove.FrameTransforms", FrameTransforms.get_schema().data)
    decoded = cls.FromString(frames.transforms("a1", angles, 5).encode())
    assert decoded.transforms[0].parent_frame_id == "world"
    assert decoded.transforms[0].child_frame_id == f"a1/{frames.model.links[0]}"
    assert_matches_fk(frames, "a1", angles, decoded)
    assert matrix_to_wxyz(np.eye(3)).tolist() == [1.0, 0.0, 0.0, 0.0]
    urdf = frames.urdf_message("a1").decode()
    assert '<link name=\\"a1/' in urdf and 'link=\\"a1/' in urdf


TOKEN = "test-token-0123456789abcdef"


def test_live_bridge_speaks_foxglove(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    with FleetHarness(tmp_path, arms=2) as harness:
        client = harness.start_fleet()
        harness.start_coordinator()
        port = free_port()
        harness.start("foxglove", ["-m", "fleet.cli.main", "foxglove", "--port", str(port)])
        wait_until(lambda: _listening(port), 20.0)
        frames = ArmFrames.load(layout_of(harness.inventory))
        reply = client.command("a2", m.MoveJoint(joint=1, angle_deg=35.0, wait_reached=True))
        assert reply.ok, reply.error
        fox = FoxgloveClient(f"ws://127.0.0.1:{port}/?token={TOKEN}")
        try:
            joints_key = "fleet/test/arm/a2/joints"
            wanted = {transforms_topic("a2"), urdf_topic("a1"), joints_key, "fleet/test/state"}
            wanted |= {"fleet/test/arm/a1/status", "fleet/test/arm/a1/diag"}
            topics = fox.wait_for_topics(wanted, 15.0)
            assert fox.server_info is not None
            tf = topics[transforms_topic("a2")]
            assert tf["schemaName"] == "foxglove.FrameTransforms" and tf["encoding"] == "protobuf"
            assert topics[joints_key]["encoding"] == "json"
            assert topics[joints_key]["schemaEncoding"] == "jsonschema"
            # Device keys are bridged with their kind's schema (issue 21).
            grip_key = "fleet/test/gripper/gx/state"
            for _ in range(3):
                client.session.put(grip_key, msgspec.json.encode(GRIP_STATE))
            grip = fox.wait_for_topics({grip_key}, 10.0)[grip_key]
            assert grip["encoding"] == "json" and "GripperState" in grip["schema"]
            fox.subscribe(transforms_topic("a2"), joints_key, urdf_topic("a2"))
            joints: dict[int, list[float]] = {}
            checked, urdf = 0, None
            for _ in range(200):
                got = fox.read(5.0)
                assert got is not None, "no message within 5 s"
                channel_id, _log_time, payload = got
                message = fox.decode(channel_id, payload)
                topic = fox.channels[channel_id]["topic"]
                if topic == joints_key:
                    joints[message["stamp_ns"]] = message["angles_deg"]
                elif topic == urdf_topic("a2"):
                    urdf = message["data"]
                else:
                    stamp = message.transforms[0].timestamp
                    angles = joints.get(stamp.seconds * 1_000_000_000 + stamp.nanos)
                    if angles is not None:
                        assert abs(angles[1] - 35.0) < 3.0
                        assert_matches_fk(frames, "a2", angles, message)
                        checked += 1
                if checked >= 3 and urdf is not None:
                    break
            assert checked >= 3 and urdf is not None and '<link name="a2/' in urdf
            client.estop(reason="foxglove test")
            stops = {"fleet/test/estop", "fleet/test/arm/a1/estop/ack", "fleet/test/estop/report"}
            fox.wait_for_topics(stops, 10.0)
        finally:
            fox.close()
            client.reset()


def _listening(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def test_recording_opens_in_3d_and_still_replays(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=1) as harness:
        client = harness.start_fleet()
        out = tmp_path / "rec.mcap"
        record = subprocess.Popen(
            [sys.executable, "-m", "fleet.cli.main", "record", "-o", str(out), "--for-s", "4"]
            + ["--inventory", str(harness.inventory_path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        reply = client.command("a1", m.MoveJoint(joint=2, angle_deg=25.0, wait_reached=True))
        assert reply.ok, reply.error
        output, _ = record.communicate(timeout=30)
        assert record.returncode == 0, output
    frames = ArmFrames.load(layout_of(harness.inventory))
    joints: dict[int, list[float]] = {}
    transforms: list[Any] = []
    urdfs = []
    with open(out, "rb") as stream:
        reader = make_reader(stream)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.topic == "fleet/test/arm/a1/joints":
                sample = m.Joints(**__import__("json").loads(message.data))
                joints[sample.stamp_ns] = sample.angles_deg
            elif channel.topic == transforms_topic("a1"):
                assert schema is not None and schema.name == "foxglove.FrameTransforms"
                assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
                transforms.append(protobuf_class(schema.name, schema.data).FromString(message.data))
            elif channel.topic == urdf_topic("a1"):
                urdfs.append(message.data)
        attachments = list(reader.iter_attachments())
    assert urdfs and b"a1/" in urdfs[0]
    assert any(a.name == "d1_550.urdf" for a in attachments)
    assert len(transforms) >= 20
    matched = 0
    for message in transforms:
        stamp = message.transforms[0].timestamp
        angles = joints.get(stamp.seconds * 1_000_000_000 + stamp.nanos)
        if angles is not None:
            assert_matches_fk(frames, "a1", angles, message)
            matched += 1
    assert matched == len(transforms)
    # The consumers that read channels by key ignore the 3D channels.
    recording = read_recording(out)
    arm, samples = recorded_joints(recording.messages)
    assert arm == "a1" and len(samples) == len(joints)
    source = replay_source(recording)
    assert list(source.layout.arms) == ["a1"]
    assert not any(r.key.startswith("/d1/") for r in source.messages)


def test_demo_option_serves_foxglove(tmp_path: Path) -> None:
    from testkit.harness import claim_domain

    domain, lock = claim_domain()
    port, fox_port = free_port(), free_port()
    repo = Path(__file__).resolve().parents[2]
    with open(tmp_path / "demo.log", "wb") as log:
        demo = subprocess.Popen(
            [sys.executable, "-m", "fleet.cli.main", "demo", "--no-viewer", "--no-dance"]
            + ["--foxglove", str(fox_port), "--for-s", "40", "--domain", str(domain)]
            + ["--endpoint", f"tcp/127.0.0.1:{port}", "--inventory", str(repo / "inventory.toml")],
            stdout=log,
            stderr=subprocess.STDOUT,
            env={**os.environ, TOKEN_ENV: TOKEN},
        )
    try:
        wait_until(lambda: _listening(fox_port) or demo.poll() is not None, 60.0)
        assert demo.poll() is None, (tmp_path / "demo.log").read_text()
        url = f"ws://127.0.0.1:{fox_port}/?token={TOKEN}"
        wait_until(lambda: url in (tmp_path / "demo.log").read_text(), 30.0)  # the intro says
        fox = FoxgloveClient(url)
        try:
            fox.wait_for_topics({transforms_topic("a1"), urdf_topic("a1")}, 20.0)
        finally:
            fox.close()
    finally:
        demo.terminate()
        demo.wait(timeout=20)
        lock.close()
