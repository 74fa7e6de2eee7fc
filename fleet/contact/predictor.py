"""Method 5's model: where each joint *should* be, given the targets the agent sent.

ASSUMPTION about the real arm: the D1's firmware smooths every new target with a first-order
lag and a speed limit, per the smoothing mode of the last ``1/2`` command (mode 0 small, mode 1
large; ``1/1`` keeps the mode, return-to-zero uses mode 1). The D1 spec gives no figures; the
constants below mirror the simulator (``fleet.sim.model.SMOOTHING``, a test keeps them equal).
On a real arm, fit them from a logged step response before relying on method 5.
"""

from __future__ import annotations

import math

ARM_SMOOTHING: dict[int, tuple[float, float]] = {0: (0.05, 180.0), 1: (0.25, 90.0)}
"""Smoothing mode -> (time constant s, speed limit deg/s)."""
STEP_S = 0.01
"""Integration step (the simulator's physics step)."""


class SmoothingPredictor:
    """Predicted angles of all joints, integrated forward from the targets sent."""

    def __init__(self, joints: int) -> None:
        self.predicted: list[float | None] = [None] * joints
        self.targets: list[float | None] = [None] * joints
        self.mode = 1
        self.time_s: float | None = None

    def advance(self, now_s: float) -> None:
        """Integrate every joint with a known state and target up to ``now_s``."""
        if self.time_s is None or now_s <= self.time_s:
            self.time_s = now_s if self.time_s is None else self.time_s
            return
        span = now_s - self.time_s
        steps = min(int(span / STEP_S) + 1, 1000)
        dt = span / steps
        tau, vmax = ARM_SMOOTHING[self.mode]
        alpha = 1.0 - math.exp(-dt / tau)
        limit = vmax * dt
        for j, (p, t) in enumerate(zip(self.predicted, self.targets)):
            if p is None or t is None:
                continue
            for _ in range(steps):
                delta = (t - p) * alpha
                p += max(-limit, min(limit, delta))
                if abs(t - p) < 1e-6:
                    p = t
                    break
            self.predicted[j] = p
        self.time_s = now_s

    def set_target(self, joint: int, target_deg: float) -> None:
        """A new target for ``joint`` (call ``advance`` to the send time first)."""
        self.targets[joint] = target_deg

    def resync(self, joint: int, angle_deg: float) -> None:
        """Make the prediction the measured angle (after a contact, or while not tracking)."""
        self.predicted[joint] = angle_deg

    def velocity_deg_s(self, joint: int) -> float:
        """The predicted speed of ``joint`` right now (0 without a prediction)."""
        p, t = self.predicted[joint], self.targets[joint]
        if p is None or t is None:
            return 0.0
        tau, vmax = ARM_SMOOTHING[self.mode]
        return max(-vmax, min(vmax, (t - p) / tau))

    def residual(self, joint: int, angle_deg: float) -> float | None:
        """Measured minus predicted, None when the joint has no prediction yet."""
        p = self.predicted[joint]
        return None if p is None else angle_deg - p
