"""Grip confirmation for ``wait = "grip"``. Pure, fed samples.

The agents' contact detector publishes ``ContactEvent`` on ``arm/<arm>/contact``; a gripper
(joint 6) event ``confirmed`` with ``grip`` confirms a grip, ``released``/``free`` ends it, and
the player trusts that word whenever the arm's agent has published one. Until then (an agent
without the detector, or no gripper event yet) a grip is confirmed from the gripper's own angle:
the gripper was commanded to close further than it got and has stopped short of that target: it
holds something. Which way is closing is the arm's (``ArmConfig.gripper_closing_sign``; by
default ``angle6`` 0 is closed).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from fleet.d1.limits import GRIPPER_JOINT
from fleet.d1.standstill import STILL_SAMPLES, is_still

SHORT_OF_TARGET_DEG = 2.0
"""A gripper still (``fleet.d1.standstill``) more than 2 deg short of its closing target holds
an object."""


@dataclass
class GripDetector:
    """Confirms a grip on one arm from its gripper angle stalling short of the target."""

    closing_sign: float = -1.0
    """Which way ``angle6`` moves when the gripper closes (-1: towards 0, the default)."""
    window: deque[float] = field(default_factory=lambda: deque(maxlen=STILL_SAMPLES))

    def add(self, angles_deg: tuple[float, ...] | list[float]) -> None:
        """Feed one joint report (seven angles)."""
        self.window.append(float(angles_deg[GRIPPER_JOINT]))

    def gripped(self, target_deg: float) -> bool:
        """True when the gripper stopped more than SHORT_OF_TARGET_DEG short of closing to
        ``target_deg``."""
        still = is_still([(angle,) for angle in self.window])
        short_deg = (target_deg - self.window[-1]) * self.closing_sign
        return still and short_deg > SHORT_OF_TARGET_DEG
