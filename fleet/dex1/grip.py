"""Grip detection for a Dex1-1 on its full-rate state stream (200-500 Hz). Pure.

The D1 contact detector's gripper logic (``fleet/contact``: method 2, a stall: the tracking
error above a threshold while the joint is nearly still; confirmed after firing continuously
for ``confirm_s``; released with hysteresis after ``release_s`` of quiet), with this device's
thresholds in its own unit (radians) and a grip only while closing (target below the
measured position). Speed is measured over ``SPEED_WINDOW_S``, not one sample interval: at
500 Hz a single 2 ms step is dominated by quantisation.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

SPEED_WINDOW_S = 0.02


@dataclass(frozen=True)
class GripChange:
    """The grip started (``grip``) or ended (``released``) at ``stamp_s``."""

    state: str
    stamp_s: float
    q_rad: float
    target_rad: float
    error_rad: float


class GripDetector:
    """Feed ``on_target`` with every target sent and ``on_sample`` with every state sample."""

    def __init__(
        self,
        error_rad: float,
        speed_rad_s: float,
        confirm_s: float,
        release_error_rad: float,
        release_s: float,
    ) -> None:
        self.error_rad = error_rad
        self.speed_rad_s = speed_rad_s
        self.confirm_s = confirm_s
        self.release_error_rad = release_error_rad
        self.release_s = release_s
        self.target_rad: float | None = None
        self.gripping = False
        self._firing_since: float | None = None
        self._quiet_since: float | None = None
        self._window: deque[tuple[float, float]] = deque(maxlen=64)

    def on_target(self, q_rad: float | None) -> None:
        """A target written to the gripper (None: none is tracked any more, e.g. stopped)."""
        self.target_rad = q_rad
        self._firing_since = None

    def speed(self) -> float | None:
        """Speed over the last ``SPEED_WINDOW_S`` (None until the window spans it)."""
        if len(self._window) < 2:
            return None
        t1, q1 = self._window[-1]
        for t0, q0 in self._window:
            if t1 - t0 <= SPEED_WINDOW_S:
                return None if t1 <= t0 else (q1 - q0) / (t1 - t0)
        return None

    def on_sample(self, q_rad: float, now_s: float) -> GripChange | None:
        """One state sample; the change it caused, if any."""
        window = self._window
        window.append((now_s, q_rad))
        while len(window) > 2 and now_s - window[1][0] >= SPEED_WINDOW_S:
            window.popleft()
        target = self.target_rad
        if target is None:
            return self._release(q_rad, now_s, 0.0, force=True)
        error = q_rad - target  # > 0: the fingers are held open of a closing target
        speed = self.speed()
        firing = error > self.error_rad and speed is not None and abs(speed) < self.speed_rad_s
        if not self.gripping:
            if not firing:
                self._firing_since = None
                return None
            if self._firing_since is None:
                self._firing_since = now_s
            if now_s - self._firing_since < self.confirm_s:
                return None
            self.gripping, self._quiet_since = True, None
            return GripChange("grip", now_s, q_rad, target, error)
        if error < self.release_error_rad:
            if self._quiet_since is None:
                self._quiet_since = now_s
            if now_s - self._quiet_since >= self.release_s:
                return self._release(q_rad, now_s, error)
        else:
            self._quiet_since = None
        return None

    def _release(
        self, q_rad: float, now_s: float, error: float, force: bool = False
    ) -> GripChange | None:
        if not self.gripping:
            return None
        self.gripping, self._firing_since, self._quiet_since = False, None, None
        target = self.target_rad if self.target_rad is not None else q_rad
        return GripChange("released", now_s, q_rad, target, error if not force else 0.0)
