"""After an enable, does the arm hold its pose? Pure, with an injected clock.

Seed 000's table says funcode 5 ``mode`` 1 enables; its note says ``mode`` runs 0..80000, 0 fully
unloaded and 80000 fully locked. Under the second reading ``mode`` 1 leaves the arm limp while the
fleet believes it enabled. So after every enable of all joints the agent watches the feedback for
``WINDOW_S``: while no motion command is written, a joint that drifts more than ``TOLERANCE_DEG``
from the pose at the enable means the arm sags, and a warning names the setting to change.
"""

from __future__ import annotations

WINDOW_S = 1.0
"""How long the pose is watched after an enable."""
TOLERANCE_DEG = 1.5
"""Drift a held joint may show (feedback noise, the settling of a servo taking the load)."""


class SagCheck:
    """One arm's watch after an enable."""

    def __init__(self) -> None:
        self._pose: tuple[float, ...] | None = None
        self._since_s = 0.0
        self._setting = ""
        self.sagged = 0
        """Enables after which the arm did not hold its pose."""

    def armed(self, pose: tuple[float, ...] | None, now: float, setting: str) -> None:
        """An enable was written at ``now`` with the arm at ``pose`` (``setting``: what to name
        in a warning, e.g. ``enable_mode 1``)."""
        self._pose, self._since_s, self._setting = pose, now, setting

    def cancel(self) -> None:
        """A motion command was written: the pose is meant to change."""
        self._pose = None

    def on_angles(self, angles: tuple[float, ...], now: float) -> str | None:
        """A warning when ``angles`` drifted from the pose within the window, else None."""
        pose = self._pose
        if pose is None:
            return None
        if now - self._since_s > WINDOW_S:
            self._pose = None  # held for the whole window
            return None
        joint, drift = max(
            ((j, abs(a - b)) for j, (a, b) in enumerate(zip(angles, pose, strict=False))),
            key=lambda jd: jd[1],
            default=(0, 0.0),
        )
        if drift <= TOLERANCE_DEG:
            return None
        self._pose = None
        self.sagged += 1
        within_s = now - self._since_s
        return (
            "the arm does not hold its pose after an enable: "
            f"joint {joint} drifted {drift:.1f} deg within {within_s:.1f} s ({self._setting}); "
            "if it is limp, its firmware reads funcode 5 `mode` as a 0..80000 strength: set "
            "enable_mode = 80000 in the inventory (or `fleet torque on --strength N`)"
        )
