"""Method 5's model: where each joint *should* be, given the targets the agent sent.

The response model is ``dynamics.py`` (dead time, lag, speed limit, optional second-order
servo per smoothing mode; ``1/1`` keeps the mode, return-to-zero uses mode 1). The D1 spec gives
no figures: without a calibration of this arm (``fleet calibrate``) the predictor uses the
simulator's own smoothing (``SIM_DEFAULT``), a guess the detector does not trust (it may raise
suspicion, never confirm). A calibration gives each joint its measured dynamics.
"""

from __future__ import annotations

from fleet.contact.dynamics import SIM_DEFAULT, ArmDynamics, JointResponse

DEFAULT_DYNAMICS = ArmDynamics(mode0=SIM_DEFAULT[0], mode1=SIM_DEFAULT[1])


class SmoothingPredictor:
    """Predicted angles of all joints, integrated forward from the targets sent."""

    def __init__(self, joints: int, dynamics: list[ArmDynamics] | None = None) -> None:
        self.dynamics = dynamics or [DEFAULT_DYNAMICS] * joints
        self._joints: list[JointResponse | None] = [None] * joints
        self._targets: list[float | None] = [None] * joints
        self.mode = 1
        self.time_s: float | None = None
        self.epochs: list[int] = [0] * joints
        """Per joint, how often its prediction was moved onto a measurement (``resync``): a
        residual before a resync and one after it are not comparable."""
        self.travel_deg: list[float] = [0.0] * joints
        """How far each prediction moved over the last ``advance``'s look-back window."""

    @property
    def predicted(self) -> list[float | None]:
        """The predicted angle of each joint (None before its first sample)."""
        return [None if r is None else r.angle_deg for r in self._joints]

    def advance(self, now_s: float, lookback_s: float = 0.0) -> None:
        """Integrate every joint with a known state up to ``now_s``; ``travel_deg`` becomes how
        far each prediction moved in the last ``lookback_s`` (since the previous call, when that
        was later). A report stamped up to ``lookback_s`` late may lag the model by that much:
        at the end of a fast, rate-limited move the model's speed *now* understates it."""
        self.travel_deg = [0.0] * len(self._joints)
        if self.time_s is None or now_s <= self.time_s:
            self.time_s = now_s if self.time_s is None else self.time_s
            return
        middle = max(self.time_s, now_s - lookback_s)
        for j, response in enumerate(self._joints):
            if response is None:
                continue
            dynamics = self.dynamics[j]
            response.advance(dynamics, self.time_s, middle)
            before = response.angle_deg
            response.advance(dynamics, middle, now_s)
            self.travel_deg[j] = abs(response.angle_deg - before)
        self.time_s = now_s

    def set_target(self, joint: int, target_deg: float) -> None:
        """A new target for ``joint`` at ``time_s`` (call ``advance`` to the send time first)."""
        self._targets[joint] = target_deg
        response = self._joints[joint]
        if response is None:
            return
        dead_s = self.dynamics[joint].mode(self.mode).dead_s
        response.command(target_deg, self.mode, self.time_s or 0.0, dead_s)
        if dead_s <= 0.0:
            response.due(self.time_s or 0.0)

    def resync(self, joint: int, angle_deg: float) -> None:
        """Make the prediction the measured angle (after a contact, or while not tracking)."""
        response = self._joints[joint]
        if response is None:
            response = self._joints[joint] = JointResponse(angle_deg)
            target = self._targets[joint]
            response.target_deg = angle_deg if target is None else target
            response.mode = self.mode
        response.hold(angle_deg)
        self.epochs[joint] += 1

    def velocity_deg_s(self, joint: int) -> float:
        """The predicted speed of ``joint`` right now (0 without a prediction)."""
        response = self._joints[joint]
        return 0.0 if response is None else response.velocity_deg_s

    def residual(self, joint: int, angle_deg: float) -> float | None:
        """Measured minus predicted, None when the joint has no prediction yet."""
        response = self._joints[joint]
        return None if response is None else angle_deg - response.angle_deg
