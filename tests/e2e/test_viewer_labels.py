"""An arm's label (and its error ball) floats just above the arm as drawn, not an arm-height
above a folded arm, and follows it up when it stretches; a jitter of a centimetre moves nothing.
A real viser server on loopback (no browser: the label's position is what the server sends)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import viser

from fleet.inventory import load_inventory
from fleet.scene3d.kinematics import ArmModel, load_urdf
from testkit.harness import free_port
from viewer.meshes import link_meshes
from viewer.scene import LABEL_ABOVE_M, LABEL_HEIGHT_M, FleetScene

INVENTORY = Path(__file__).resolve().parents[2] / "inventory.toml"


def test_labels_follow_the_arms_height() -> None:
    urdf = load_urdf()
    model = ArmModel.from_urdf(urdf)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        scene = FleetScene(
            server, load_inventory(INVENTORY).arms, model, link_meshes(urdf, model.links)
        )
        base_z = scene.base[:, 2, 3]

        def heights(angles_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            _, pos = scene._poses(angles_deg)  # noqa: SLF001  (the drawn pose, as render does)
            scene._place_labels(pos)  # noqa: SLF001
            labels = np.array([label.position[2] for label in scene._labels])  # noqa: SLF001
            return labels - base_z, pos[:, :, 2].max(axis=0) - base_z

        upright = np.zeros((len(scene.arms), 7))
        height, top = heights(upright)
        assert np.allclose(height, np.minimum(top + LABEL_ABOVE_M, LABEL_HEIGHT_M))
        lying = upright.copy()
        lying[:, 1] = 80.0  # the shoulder tips the arm over: far lower
        low, low_top = heights(lying)
        assert (low_top < top - 0.1).all()
        assert (low < height - 0.1).all(), "the label stayed an arm-height above a folded arm"
        assert np.allclose(low, np.minimum(low_top + LABEL_ABOVE_M, LABEL_HEIGHT_M))
        _, up = scene._poses(upright)  # noqa: SLF001
        scene._place_labels(up)  # noqa: SLF001
        # A centimetre of jitter moves no label (no resend per sample).
        before = [label.position for label in scene._labels]  # noqa: SLF001
        up[:, :, 2] += 0.01
        scene._place_labels(up)  # noqa: SLF001
        assert [label.position for label in scene._labels] == before  # noqa: SLF001
    finally:
        server.stop()


def test_the_first_view_and_fit_view_frame_what_other_scenes_add() -> None:
    """The G1s (``frame_also``) are framed with the arms' reach: at start and on Fit view."""
    urdf = load_urdf()
    model = ArmModel.from_urdf(urdf)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        meshes = link_meshes(urdf, model.links)
        scene = FleetScene(server, load_inventory(INVENTORY).arms, model, meshes)
        head = np.array([[-1.0, 2.0, 1.7]])  # a humanoid's head, beside the arms
        scene.frame_also(lambda: head)
        assert any(np.allclose(p, head[0]) for p in scene.view_points())
    finally:
        server.stop()
