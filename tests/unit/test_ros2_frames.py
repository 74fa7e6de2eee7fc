"""``fleet ros2``'s plain-Python TF frames (fleet/ros2/frames.py) against the viewer's numpy
kinematics (fleet/scene3d/kinematics.py, the definition): every link's world pose composed from our
static and moving transforms is the viewer's, at random poses, signs and gripper ranges."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from fleet.cli.ros2_cmd import UrdfArms
from fleet.inventory import load_inventory
from fleet.ros2 import frames
from fleet.scene3d import kinematics as k


def _matrix(xyz: tuple[float, ...], xyzw: tuple[float, ...]) -> np.ndarray:
    x, y, z, w = xyzw
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = xyz
    return m


@pytest.fixture(scope="module")
def arms(tmp_path_factory: pytest.TempPathFactory) -> UrdfArms:
    path = Path(tmp_path_factory.mktemp("inv")) / "inventory.toml"
    path.write_text(
        '[fleet]\nname = "lab"\n[zenoh]\nendpoints = ["tcp/127.0.0.1:7447"]\n'
        '[defaults]\ninterface = "lo"\nsimulated = true\n'
        '[arms.a1]\nsuffix = "_1"\nbase_xyz = [0.1, -0.4, 0.05]\nbase_rpy_deg = [0, 10, 90]\n'
        "joint_sign = [-1, 1, 1, -1, 1, 1, -1]\n"
        '[arms.a2]\nsuffix = "_2"\n',
        encoding="utf-8",
    )
    return UrdfArms(load_inventory(path))


def test_wire_to_q_is_the_viewers() -> None:
    rng = random.Random(7)
    for _ in range(200):
        angles = [rng.uniform(-180, 180) for _ in range(6)] + [rng.uniform(-10, 80)]
        sign = [rng.choice((1, -1)) for _ in range(7)]
        grip = (rng.uniform(-5, 5), rng.uniform(40, 90))
        ours = frames.wire_to_q(angles, sign, grip)
        assert ours == pytest.approx(list(k.wire_to_q([angles], sign, grip)[0]), abs=1e-12)


@pytest.mark.parametrize("arm", ["a1", "a2"])
def test_every_link_is_where_the_viewer_puts_it(arms: UrdfArms, arm: str) -> None:
    model = arms.model
    p = arms.layout.arms[arm]
    rng = random.Random(arm)
    for _ in range(50):
        angles = [rng.uniform(-150, 150) for _ in range(6)] + [rng.uniform(0, 65)]
        q = arms.q(arm, angles)
        expected = (
            k.base_transforms(p.base_xyz, p.base_rpy_deg)[0]
            @ k.forward(
                model,
                k.wire_to_q([angles], p.joint_sign, (p.gripper_closed_deg, p.gripper_open_deg)),
            )[0]
        )
        edges = [(t.parent, t.child, t.xyz, t.xyzw) for t in arms.static_transforms(arm)]
        moving = zip(arms.moving_frames(arm), arms.moving_poses(arm, q), strict=True)
        edges += [(parent, child, pose[:3], pose[3:]) for (parent, child), pose in moving]
        world = {"world": np.eye(4)}
        while len(world) <= len(model.links):  # parents first, in whatever order edges come
            for parent, child, xyz, xyzw in edges:
                if parent in world and child not in world:
                    world[child] = world[parent] @ _matrix(xyz, xyzw)
        for i, link in enumerate(model.links):
            np.testing.assert_allclose(world[f"{arm}/{link}"], expected[i], atol=1e-9)
    assert len(arms.moving_frames(arm)) == 8  # Joint1..6 and the two fingers
