"""An arm's reach (viewer/reach.py), pure: the sampled hull holds every pose the joint limits
allow, drawn at random, within a centimetre and a half along any direction."""

from __future__ import annotations

import numpy as np

from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.scene3d.kinematics import ArmModel, forward, load_urdf, wire_to_q
from viewer.meshes import link_meshes
from viewer.reach import directions, outer_points, reach_points
from viewer.scene import _box_corners


def test_every_pose_within_the_limits_lies_inside_the_reach() -> None:
    urdf = load_urdf()
    model = ArmModel.from_urdf(urdf)
    meshes = link_meshes(urdf, model.links)
    links = [model.links.index(mesh.link) for mesh in meshes]
    corners = np.stack([_box_corners(mesh.vertices) for mesh in meshes])
    sign, gripper = np.array([1, 1, -1, 1, 1, -1, 1]), (10.0, 60.0)
    hull = reach_points(model, links, corners, tuple(sign), gripper)
    rng = np.random.default_rng(3)
    low, high = np.array(JOINT_RANGE_DEG).T
    low[6], high[6] = gripper
    world = forward(model, wire_to_q(rng.uniform(low, high, (3000, 7)), sign, gripper))[:, links]
    points = np.einsum("nkij,kcj->nkci", world[..., :3, :3], corners) + world[..., None, :3, 3]
    toward = directions(500)
    # The poses' farthest points along each direction (outer_points works in chunks: the whole
    # (points, directions) product was 0.8 GB and took most of this test's time).
    farthest = outer_points(points.reshape(-1, 3), toward)
    excess = (farthest @ toward.T).max(axis=0) - (hull @ toward.T).max(axis=0)
    assert excess.max() < 0.015, f"a pose reaches {excess.max():.3f} m beyond the hull"
    assert len(hull) <= 256  # a few points per arm: cheap to frame for 200 arms
