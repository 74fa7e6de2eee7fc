"""The G1 in 3D without transport: Foxglove's transforms compose back to where the viewer draws
every link (one body model, fleet/scene3d/g1_body.py); the recorded layout keeps the devices
and refuses a hostile one; a malformed lowstate never decodes (so it is never drawn)."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from foxglove.messages import FrameTransforms

from fleet.g1.kind import KIND as G1
from fleet.g1.messages import G1LowState
from fleet.record.errors import RecordError
from fleet.record.layout import (
    ArmPlacement,
    DevicePlacement,
    FleetLayout,
    devices_from_keys,
    layout_from_metadata,
    layout_metadata,
)
from fleet.scene3d.frames3d import (
    G1_LOWSTATE,
    FleetFrames,
    G1Frames,
    RecordingExtras,
    transforms_topic,
)
from fleet.scene3d.g1_body import SPACING_M
from fleet.wire import keys, payloads
from testkit.foxglove_client import protobuf_class, stamp_ns_of, world_from_links

LAYOUT = FleetLayout(
    "lab",
    {"a1": ArmPlacement(base_xyz=(0.0, 0.5, 0.0))},
    {
        "gl": DevicePlacement(kind="gripper", mount="a1"),
        "h1": DevicePlacement(kind="g1", base_xyz=(2.0, -1.0, 0.0), base_yaw_deg=90.0),
        "h2": DevicePlacement(kind="g1"),  # no base: in the row left of the arms
    },
)


def _low(q15: float = 0.0, roll: float = 0.0, pitch: float = 0.0) -> G1LowState:
    q = [0.0] * 29
    q[15], q[3] = q15, 0.4  # left shoulder pitch, left knee
    return G1LowState(
        stamp_ns=1_700_000_000_123_456_789,
        q_rad=q,
        imu_rpy=[roll, pitch, 0.3],
        imu_quaternion=[1.0, 0.0, 0.0, 0.0],
        tick=7,
        bad_samples=0,
    )


def test_foxglove_transforms_are_the_viewers_pose() -> None:
    frames = G1Frames.load(LAYOUT)
    assert frames.devices == ("h1", "h2")
    low = _low(q15=-1.0, roll=0.1, pitch=-0.2)
    cls = protobuf_class("foxglove.FrameTransforms", FrameTransforms.get_schema().data)
    message = cls.FromString(frames.transforms("h1", low).encode())
    assert stamp_ns_of(message) == low.stamp_ns
    assert message.transforms[0].parent_frame_id == "world"
    assert message.transforms[0].child_frame_id == "h1/pelvis"
    got = world_from_links(message)
    expected = frames.link_matrices("h1", low)
    for i, link in enumerate(frames.body.model.links):
        np.testing.assert_allclose(got[f"h1/{link}"], expected[i], atol=1e-6, rtol=0)
    # Where it stands: its own base, turned by its yaw, the pelvis at standing height.
    pelvis = frames.link_matrices("h1", _low())[0]
    assert pelvis[:2, 3].tolist() == pytest.approx([2.0, -1.0])
    assert pelvis[2, 3] == pytest.approx(frames.body.pelvis_height_m)
    # h2 has no base: second place of the row left of the arms, as the viewer stands it.
    h2 = frames.link_matrices("h2", _low())[0][:3, 3].tolist()
    assert h2 == pytest.approx([SPACING_M, 0.5 + SPACING_M, frames.body.pelvis_height_m])


def test_fleet_frames_pose_arms_by_joints_and_g1s_by_lowstate() -> None:
    frames = FleetFrames.load(LAYOUT)
    assert frames.units == ("a1", "h1", "h2")  # a gripper has no frames of its own
    assert b"h1/pelvis" in frames.urdf_message("h1") and b"a1/" in frames.urdf_message("a1")
    extras = RecordingExtras(frames)
    derived = extras.derive("h1", G1_LOWSTATE, _low())
    assert [d.topic for d in derived] == [transforms_topic("h1")]
    assert derived[0].schema_name == "foxglove.FrameTransforms"
    assert extras.derive("h1", keys.JOINTS, _low()) == []  # a G1 has no joints channel
    assert extras.derive("gl", "gripper/state", object()) == []
    assert extras.derive("zz", G1_LOWSTATE, _low()) == []  # not laid out
    assert {name for name, _data, _type in extras.attachments()} == {
        "d1_550.urdf",
        "g1_29dof.urdf",
    }
    assert [m.topic for m in extras.initial()] == [
        f"/d1/{u}/robot_description" for u in frames.units
    ]


def test_the_layout_keeps_the_devices_and_refuses_hostile_ones() -> None:
    entries = layout_metadata(LAYOUT)
    assert layout_from_metadata("f.mcap", entries) == LAYOUT
    older = msgspec.json.encode({"fleet": "lab", "arms": {}}).decode()
    assert layout_from_metadata("old.mcap", {"json": older}).devices == {}
    for devices, why in [
        ({"h1": {"kind": "tank"}}, "kind 'tank'"),
        ({"h 1": {"kind": "g1"}}, "not a name"),
        ({"h1": {"kind": "g1", "base_xyz": [1e9, 0, 0]}}, "malformed"),
        ({"h1": {"kind": "g1", "base_yaw_deg": "north"}}, "malformed"),
    ]:
        text = msgspec.json.encode({"fleet": "lab", "arms": {}, "devices": devices}).decode()
        with pytest.raises(RecordError, match=why):
            layout_from_metadata("bad.mcap", {"json": text})
    found = devices_from_keys(
        "lab",
        [
            "fleet/lab/arm/a1/joints",
            "fleet/lab/g1/h1/lowstate",
            "fleet/lab/gripper/gl/state",
            "fleet/lab/g1/h1/state",
            "fleet/other/g1/x9/state",
            "junk",
        ],
    )
    assert found == {"h1": DevicePlacement(kind="g1"), "gl": DevicePlacement(kind="gripper")}


@pytest.mark.parametrize(
    "change",
    [
        {"q_rad": [0.0] * 28},
        {"q_rad": [0.0] * 30},
        {"q_rad": [0.0] * 28 + [11.0]},
        {"imu_rpy": [0.0, 0.0]},
        {"imu_quaternion": [1.0, 0.0, 0.0]},
        {"q_rad": "x"},
    ],
)
def test_a_malformed_lowstate_never_decodes(change: dict[str, object]) -> None:
    good = msgspec.json.encode(_low())
    assert G1.payloads[keys.LOWSTATE].decode(good) == _low()
    data = msgspec.json.encode({**msgspec.json.decode(good), **change})
    with pytest.raises(payloads.PayloadError, match="g1 lowstate"):
        G1.payloads[keys.LOWSTATE].decode(data)
    overflow = good.replace(b"0.4", b"1e999", 1)  # JSON has no inf: msgspec refuses it too
    with pytest.raises(payloads.PayloadError):
        G1.payloads[keys.LOWSTATE].decode(overflow)
    assert math.isfinite(max(_low().q_rad))
