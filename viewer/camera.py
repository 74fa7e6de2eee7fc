"""Framing the fleet: where the camera goes so every arm fills the view (at start and on "Fit").
What is framed is every arm's whole reach (viewer/reach.py), not the pose of the moment.

A fixed viewing direction (from the front right, above: the view an operator expects), the
target at the centre of the arms' bounding box, and the distance that puts the farthest point
just inside the view's edges, for this browser's field of view and aspect. Pure numpy.

The first viewer framed the fleet with a rule of thumb (distance from the spread of the bases);
with three.js' default 75 deg field of view the arms filled about 15 % of the picture.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

VIEW_DIRECTION = np.array([1.0, -1.0, 0.7])
"""From the target towards the camera (world, +z up)."""
UP = np.array([0.0, 0.0, 1.0])
MARGIN = 0.08
"""Fraction of the half-view left free around the arms."""

DEFAULT_ASPECT = 1.6
"""Canvas width / height assumed before a browser tells its own (1280x800)."""
DEFAULT_WIDTH_PX = 1280.0
PANEL_PX = 410.0
"""The width of viser's control panel (``control_width="large"``) over the canvas' right side."""
MIN_DISTANCE_M = 0.5
FOV_RAD = np.deg2rad(45.0)
"""The viewer's vertical field of view. three.js' default of 75 deg distorts a row of arms seen
from a corner (the near arm looms, the far one shrinks) and, framed closely, puts the camera
inside the near arm's reach; 45 deg is a usual lens for a robot cell."""


def camera_axes(
    direction: npt.NDArray[np.float64], up: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(back, right, true up) unit vectors of a camera looking along ``-direction``."""
    back = direction / np.linalg.norm(direction)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    return back, right, np.cross(back, right)


def usable_right_edge(image_width_px: float) -> float:
    """The right edge of the part of the view the control panel leaves free, in normalized
    device coordinates (1.0: the canvas' own edge)."""
    return float(np.clip(1.0 - 2.0 * PANEL_PX / max(image_width_px, 1.0), -0.5, 1.0))


def fit_view(
    points: npt.NDArray[np.float64],
    fov_rad: float,
    aspect: float,
    right_edge: float = 1.0,
    direction: npt.NDArray[np.float64] = VIEW_DIRECTION,
    up: npt.NDArray[np.float64] = UP,
    margin: float = MARGIN,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(camera position, look-at point) of the closest camera looking along ``-direction`` that
    sees every one of ``points`` (M, 3) inside the view between the left edge and
    ``right_edge`` (normalized device coordinates: the panel covers the rest), shrunk by
    ``margin``, centred there, for vertical field of view ``fov_rad`` and ``aspect``.

    With the orientation fixed, "q is inside" is linear in the camera position c (in the
    camera's right/up/back basis): q_r - c_r <= r t_h (c_b - q_b) and c_r - q_r <= t_h (c_b -
    q_b), so c_r + r t_h c_b >= max(q_r + r t_h q_b) =: A and -c_r + t_h c_b >=
    max(-q_r + t_h q_b) =: B, hence c_b >= (A + B) / ((1 + r) t_h); the same for up (r = 1).
    The closest camera takes the larger bound, and centres c_r and c_u in the interval each
    axis then allows. (Centring the world bounding box instead framed a row of arms
    off-centre: perspective makes the near end larger.)"""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, 3))
    back, right, true_up = camera_axes(np.asarray(direction, dtype=float), up)
    q_r, q_u, q_b = pts @ right, pts @ true_up, pts @ back
    tan_v = np.tan(fov_rad / 2.0) * (1.0 - margin)
    tan_h = tan_v * aspect
    r = right_edge - margin * (1.0 + right_edge) / 2.0  # the margin inside the usable part
    r = max(r, -0.5)
    a, b = np.max(q_r + r * tan_h * q_b), np.max(-q_r + tan_h * q_b)
    c, d = np.max(q_u + tan_v * q_b), np.max(-q_u + tan_v * q_b)
    c_b = max(
        (a + b) / ((1.0 + r) * tan_h),
        (c + d) / (2.0 * tan_v),
        float(np.max(q_b)) + MIN_DISTANCE_M,
    )
    c_r = ((a - r * tan_h * c_b) + (tan_h * c_b - b)) / 2.0
    c_u = ((c - tan_v * c_b) + (tan_v * c_b - d)) / 2.0
    position = right * c_r + true_up * c_u + back * c_b
    look_at = position - back * (c_b - float(np.mean([q_b.min(), q_b.max()])))
    return position, look_at
