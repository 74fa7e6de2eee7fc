"""The viewer's pure parts: the URDF, the wire -> URDF mapping, forward kinematics, looks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yourdfpy

from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.scene3d.kinematics import (
    FINGER_JOINTS,
    Q_JOINTS,
    URDF_PATH,
    ArmModel,
    base_transforms,
    forward,
    load_urdf,
    matrix_to_wxyz,
    wire_to_q,
)
from viewer.commands import clamp_to_limits
from viewer.meshes import link_meshes
from viewer.scene import NORMAL, OFFLINE, STALE, STOPPED, label_text, tinted

# The table, from Unitree's d1_550_description: origin, axis, limit.
SPEC = {
    "Joint1": ((0, 0, 0.0738), (0, 0, -1), (-2.36, 2.36)),
    "Joint2": ((0, -0.0276, 0.0578), (0, 1, 0), (-1.57, 1.57)),
    "Joint3": ((0, -0.0004, 0.27), (0, 1, 0), (-1.57, 1.57)),
    "Joint4": ((0.05, 0.0275, 0.041325), (1, 0, 0), (-2.36, 2.36)),
    "Joint5": ((0.15468, -0.0258, 0.0001), (0, 1, 0), (-1.57, 1.57)),
    "Joint6": ((0.0777, 0.025822, -0.0010718), (1, 0, 0), (-2.36, 2.36)),
    "Joint_L": ((0.0718, -0.033778, 0.0031), (0, 1, 0), (0.0, 0.033)),
    "Joint_R": ((0.0718, 0.033022, 0.0031), (0, -1, 0), (0.0, 0.033)),
}


@pytest.fixture(scope="module")
def urdf() -> yourdfpy.URDF:
    return load_urdf()


@pytest.fixture(scope="module")
def model(urdf: yourdfpy.URDF) -> ArmModel:
    return ArmModel.from_urdf(urdf)


def test_urdf_loads_with_yourdfpy_and_matches_the_spec_table(urdf: yourdfpy.URDF) -> None:
    full = yourdfpy.URDF.load(str(URDF_PATH), build_scene_graph=True, load_meshes=True)
    assert full.scene is not None and len(full.scene.geometry) >= 9
    assert tuple(urdf.actuated_joint_names) == Q_JOINTS
    for name, (xyz, axis, (low, high)) in SPEC.items():
        joint = urdf.joint_map[name]
        np.testing.assert_allclose(joint.origin[:3, 3], xyz, atol=1e-9, err_msg=name)
        np.testing.assert_allclose(joint.origin[:3, :3], np.eye(3), atol=1e-12, err_msg=name)
        np.testing.assert_allclose(joint.axis, axis, err_msg=name)
        assert (joint.limit.lower, joint.limit.upper) == (low, high), name
        assert joint.type == ("prismatic" if name in FINGER_JOINTS else "revolute")


def test_masses_sum_to_the_spec_total(urdf: yourdfpy.URDF) -> None:
    total = sum(link.inertial.mass for link in urdf.robot.links if link.inertial is not None)
    assert total == pytest.approx(3.152, abs=1e-9)


def test_every_link_has_a_mesh_and_its_own_colour(urdf: yourdfpy.URDF, model: ArmModel) -> None:
    meshes = link_meshes(urdf, model.links)
    assert [m.link for m in meshes] == list(model.links)
    assert len({m.rgb for m in meshes}) == len(meshes)
    for mesh in meshes:
        assert mesh.vertices.shape[1] == 3 and mesh.faces.shape[1] == 3
        assert mesh.faces.max() < len(mesh.vertices)


def test_stretched_reach_shoulder_to_flange_is_about_556_mm(model: ArmModel) -> None:
    q = np.zeros((2, len(Q_JOINTS)))
    q[0, 2] = -math.pi / 2  # elbow straightened: the forearm continues the upper arm upwards
    q[1, 2] = -math.pi / 2
    q[1, 0] = 1.0  # a base rotation does not change the reach
    links = forward(model, q)
    shoulder, flange = model.links.index("Link2"), model.links.index("Link6")
    reach = np.linalg.norm(links[:, flange, :3, 3] - links[:, shoulder, :3, 3], axis=1)
    np.testing.assert_allclose(reach, 0.556, atol=0.003)
    # Stretched means straight up: the flange is (almost) above the shoulder.
    up = links[0, flange, 2, 3] - links[0, shoulder, 2, 3]
    assert up > 0.55


def test_forward_kinematics_equals_yourdfpy(model: ArmModel) -> None:
    reference = yourdfpy.URDF.load(str(URDF_PATH), build_scene_graph=True, load_meshes=False)
    rng = np.random.default_rng(4)
    q = rng.uniform(-1.5, 1.5, (6, len(Q_JOINTS)))
    q[:, 6:] = rng.uniform(0.0, 0.033, (6, 2))
    links = forward(model, q)
    for k in range(len(q)):
        reference.update_cfg(q[k])
        for i, name in enumerate(model.links):
            np.testing.assert_allclose(
                links[k, i], reference.get_transform(name, "base_link"), atol=1e-12
            )


def test_wire_to_q_degrees_to_radians_with_per_joint_signs() -> None:
    angles = [[10.0, -20.0, 30.0, 45.0, -90.0, 135.0, 0.0]]
    plus = wire_to_q(angles, [1] * 7)
    np.testing.assert_allclose(plus[0, :6], np.radians(angles[0][:6]))
    flipped = wire_to_q(angles, [-1, 1, 1, -1, 1, 1, 1])
    np.testing.assert_allclose(flipped[0, :6], np.radians([-10.0, -20.0, 30.0, -45.0, -90.0, 135]))


def test_wire_to_q_gripper_maps_0_to_65_deg_onto_the_finger_travel() -> None:
    angles = np.zeros((5, 7))
    angles[:, 6] = [0.0, 32.5, 65.0, 80.0, -5.0]  # closed, half, open, beyond both ends
    q = wire_to_q(angles, [1] * 7)
    # Both finger axes point inwards: 0 m is open, 0.033 m closed.
    np.testing.assert_allclose(q[:, 6], [0.033, 0.0165, 0.0, 0.0, 0.033])
    np.testing.assert_allclose(q[:, 6], q[:, 7])
    reversed_servo = wire_to_q(angles, [1, 1, 1, 1, 1, 1, -1])
    np.testing.assert_allclose(reversed_servo[:, 6], [0.0, 0.0165, 0.033, 0.033, 0.0])


def test_closed_gripper_brings_the_fingers_together(model: ArmModel) -> None:
    angles = np.zeros((2, 7))
    angles[1, 6] = 65.0
    links = forward(model, wire_to_q(angles, [1] * 7))
    left, right = model.links.index("Link_L"), model.links.index("Link_R")
    gap = np.linalg.norm(links[:, left, :3, 3] - links[:, right, :3, 3], axis=1)
    assert gap[0] < 0.005  # closed: the finger frames nearly meet
    assert gap[1] == pytest.approx(0.0668, abs=0.001)  # open: 65 mm stroke and a bit


def test_wire_to_q_rejects_the_wrong_number_of_angles() -> None:
    with pytest.raises(ValueError, match="expected 7"):
        wire_to_q([[0.0] * 6], [1] * 7)


def test_base_pose_and_quaternions() -> None:
    base = base_transforms([[1.0, 2.0, 0.0]], [[0.0, 0.0, 90.0]])
    np.testing.assert_allclose(base[0, :3, 3], [1.0, 2.0, 0.0])
    np.testing.assert_allclose(base[0, :3, :3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    wxyz = matrix_to_wxyz(base[:, :3, :3])[0]
    np.testing.assert_allclose(np.abs(wxyz), [math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
    rng = np.random.default_rng(2)
    rotations = base_transforms(np.zeros((50, 3)), rng.uniform(-180, 180, (50, 3)))[:, :3, :3]
    q = matrix_to_wxyz(rotations)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    w, x, y, z = q.T
    rebuilt = np.stack(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    ).transpose(2, 0, 1)
    np.testing.assert_allclose(rebuilt, rotations, atol=1e-9)


def test_jog_targets_are_clamped_to_the_wire_limits() -> None:
    for joint, (low, high) in enumerate(JOINT_RANGE_DEG):
        assert clamp_to_limits(joint, high + 50.0) == high
        assert clamp_to_limits(joint, low - 50.0) == low
        assert clamp_to_limits(joint, (low + high) / 2) == (low + high) / 2


def test_looks_tint_and_label() -> None:
    codes = np.array([NORMAL, STALE, OFFLINE, STOPPED], dtype=np.int8)
    colours = tinted((20, 100, 200), codes)
    assert tuple(colours[0]) == (20, 100, 200)
    assert colours[3, 0] > colours[3, 2]  # stopped: red dominates
    assert label_text("a1", NORMAL, False) == "a1"
    assert label_text("a1", OFFLINE, False) == "a1 · OFFLINE"
    assert label_text("a1", STOPPED, True) == "a1 · STOPPED ERROR"


def test_the_fleet_table_shows_contact_and_the_stop_reason() -> None:
    """Contact and the stop's reason were nowhere in the viewer's table (issue 15)."""
    from fleet.wire import messages as m
    from viewer.panels import FleetTable
    from viewer.state import Snapshot

    stopped = m.ArmStatus(stamp_ns=1, link="ok", estopped=True, stop_reason="stopped by ann: snag")
    contact = np.zeros((2, 7), dtype=bool)
    contact[1, 2] = contact[1, 3] = True
    snapshot = Snapshot(
        arms=("a1", "a2"),
        angles_deg=np.zeros((2, 7)),
        joints_age_s=np.array([0.1, 0.1]),
        status=(stopped, m.ArmStatus(stamp_ns=1, link="ok")),
        online=np.array([True, True]),
        contact=contact,
    )
    table = FleetTable().html(snapshot)
    assert ">contact</th>" in table
    assert ">j2 j3</td>" in table and ">no</td>" in table
    assert "a1: stopped by ann: snag" in table


def test_the_legend_explains_every_colour_of_the_scene() -> None:
    """The amber link (contact) and the tints were explained nowhere (issue 15)."""
    from viewer.scene import CONTACT_RGB, OFFLINE_RGB, STALE_RGB, STOP_RGB, legend_html

    legend = legend_html()
    for rgb, word in ((STALE_RGB, "stale"), (OFFLINE_RGB, "OFFLINE"), (STOP_RGB, "STOPPED"),
                      (CONTACT_RGB, "contact")):  # fmt: skip
        swatch = "#" + "".join(f"{int(c):02x}" for c in rgb)
        assert swatch in legend and f"<b>{word}</b>" in legend, (word, legend)


def test_a_partly_calibrated_arm_does_not_read_calibrated() -> None:
    """After ``fleet calibrate a1 --joint 0`` the arm's folder said "calibrated" (issue 26)."""
    from fleet.wire import messages as m
    from viewer.arm_panel import _model_text

    status = m.ArmStatus(stamp_ns=1, link="ok", contact_model="partial")
    assert _model_text(status).startswith("partly calibrated")


def test_the_legend_explains_the_red_ball() -> None:
    """The Legend lacked "red ball = error" (issue 26)."""
    from viewer.scene import legend_html

    assert "red ball" in legend_html() and "error" in legend_html()
