"""An arm's reach: the points the camera must see so that the arm stays in view at every pose
its joint limits allow (the first view and "Fit view" frame this, not the pose of the moment:
framed on the pose of the moment, an arm of the dancing demo swung out of the view's edge).

The reach is sampled, not solved: a grid over wire joints 1..5 and the gripper (joint 0 held
at 0), the corners of every drawn link's bounding box at each grid pose, reduced to the points
that are farthest along 256 directions (an outer hull: framing only ever asks for maxima of
linear functions of the points). Joint 0 turns everything above it rigidly about its axis, so
the hull is then turned through joint 0's range instead of multiplying the grid by it (about
0.05 s instead of seconds). Grid and hull miss the true reach by a few centimetres at most; the
view's margin (viewer/camera.py ``MARGIN``) is larger than that. Pure numpy.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from fleet.d1.limits import GRIPPER_JOINT, JOINT_COUNT, JOINT_RANGE_DEG
from fleet.scene3d.kinematics import ArmModel, forward, wire_to_q

FloatArray = npt.NDArray[np.float64]

STEPS = (19, 7, 7, 3, 5, 2)
"""Grid values per wire joint 0..5 over its range (joint 0: the turns of the hull)."""
DIRECTIONS = 256


def directions(count: int = DIRECTIONS) -> FloatArray:
    """(count, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / count)
    azimuth = np.pi * (1.0 + 5**0.5) * i
    return np.stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1
    )


def outer_points(points: FloatArray, toward: FloatArray | None = None) -> FloatArray:
    """The points of ``points`` (M, 3) that are farthest along one of ``toward`` (D, 3)."""
    toward = directions() if toward is None else toward
    columns = np.arange(len(toward))
    best_score = np.full(len(toward), -np.inf)
    best = np.zeros((len(toward), 3))
    for start in range(0, len(points), 20_000):  # (chunk, D) products stay small
        part = points[start : start + 20_000]
        score = toward @ part.T  # (D, chunk): argmax along rows is the fast direction
        top = np.argmax(score, axis=1)
        found = score[columns, top]
        better = found > best_score
        best_score[better] = found[better]
        best[better] = part[top][better]
    return np.unique(best[np.isfinite(best_score)], axis=0)


def reach_points(
    model: ArmModel,
    link_index: Sequence[int],
    corners: FloatArray,
    joint_sign: Sequence[float],
    gripper_deg: tuple[float, float],
) -> FloatArray:
    """(M, 3) outer points, in the arm's base frame, of the boxes ``corners`` (K, 8, 3) of the
    links ``link_index`` (K) over every pose within the joint limits (``JOINT_RANGE_DEG``, the
    gripper between ``gripper_deg``)."""
    ranges = [*JOINT_RANGE_DEG[:GRIPPER_JOINT], tuple(sorted(gripper_deg))]
    axes = [np.linspace(low, high, n) for (low, high), n in zip(ranges, STEPS, strict=False)]
    axes[0] = np.zeros(1)
    axes.append(np.array(ranges[GRIPPER_JOINT], dtype=float))
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, JOINT_COUNT)
    world = forward(model, wire_to_q(grid, joint_sign, gripper_deg))[:, list(link_index)]
    pts = np.einsum("nkij,kcj->nkci", world[..., :3, :3], corners) + world[..., None, :3, 3]
    hull = outer_points(pts.reshape(-1, 3))
    # Joint 0 turns every link it carries rigidly: turn the hull through its range.
    turns = np.zeros((STEPS[0] + 1, JOINT_COUNT))  # row 0: joint 0 at 0, where the hull is
    turns[1:, 0] = np.linspace(*JOINT_RANGE_DEG[0], STEPS[0])
    turns[:, GRIPPER_JOINT] = gripper_deg[0]
    carrier = model.q_index.index(0)
    frames = forward(model, wire_to_q(turns, joint_sign, gripper_deg))[:, carrier]
    moves = frames[1:] @ np.linalg.inv(frames[0])  # (T, 4, 4): joint 0 at 0 -> joint 0 at each turn
    turned = np.einsum("tij,mj->tmi", moves[:, :3, :3], hull) + moves[:, None, :3, 3]
    return outer_points(np.vstack([hull, turned.reshape(-1, 3)]))
