"""Contact physics of the simulated arm: obstacles a joint pushes against, objects the gripper
closes on, servo hunting near an obstacle, an obstacle that moves into a held joint.

Pure and deterministic (time comes from the model's fixed steps). The compliance model: the
position servo (stiffness k_m) pushes against an obstacle (stiffness k_o); at rest the joint
penetrates ``compliance * (target - obstacle)`` past the obstacle, compliance = k_m/(k_m+k_o).
A compliance of 0 is a rigid wall (the old ``stall`` fault), 0.1 a firm rubber stop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class Obstacle:
    """One obstacle on one joint. ``side`` +1 keeps the joint below ``angle_deg``, -1 above it,
    0 = decided by the side the joint is on when the obstacle is first evaluated."""

    angle_deg: float
    compliance: float = 0.1
    hunting_deg: float = 0.0
    hunting_hz: float = 3.0
    to_deg: float | None = None
    speed_deg_s: float = 0.0
    error_after_s: float | None = None
    side: int = 0
    pushing_s: float = 0.0
    """Runtime: how long the joint has been pushing against it without a break (seconds;
    servo hunting lifts the joint off and starts it again)."""
    met_s: float | None = None
    """Runtime: the model time at the start of the first step in which the joint was blocked
    (the contact's onset, whatever hunting did after it; the benchmark's label)."""

    @property
    def raises_error(self) -> bool:
        """True while the (simulated) arm flags ``error_status`` for this push."""
        return self.error_after_s is not None and self.pushing_s >= self.error_after_s


def constrain(obstacle: Obstacle, current: float, new: float, target: float, dt: float) -> float:
    """Where the joint ends this step (it wanted to go from ``current`` to ``new``)."""
    if obstacle.to_deg is not None and obstacle.speed_deg_s > 0:
        gap = obstacle.to_deg - obstacle.angle_deg
        step = obstacle.speed_deg_s * dt
        obstacle.angle_deg += max(-step, min(step, gap))
    if obstacle.side == 0:
        obstacle.side = 1 if current <= obstacle.angle_deg else -1
    side = obstacle.side
    wall = obstacle.angle_deg
    push = side * (target - wall)  # > 0: the servo pushes into the obstacle
    limit = wall + side * obstacle.compliance * max(0.0, push)
    blocked = side * (new - limit) >= 0.0
    if not blocked:
        obstacle.pushing_s = 0.0
        return new
    obstacle.pushing_s += dt
    position = limit
    if obstacle.hunting_deg > 0.0 and push > 0.0:
        # Servo hunting: the controller overshoots off the obstacle and comes back.
        phase = 2.0 * math.pi * obstacle.hunting_hz * obstacle.pushing_s
        position -= side * obstacle.hunting_deg * 0.5 * (1.0 - math.cos(phase))
    return position
