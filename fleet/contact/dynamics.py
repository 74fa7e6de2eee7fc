"""How a D1 joint follows its target: one response model for the simulator, the detector's
predictor (method 5) and the calibration fit. Pure.

The D1 spec gives no figures for the firmware's command smoothing, so the model is a family
wide enough for any plausible arm: per smoothing mode, a dead time, then a
reference that moves towards the target with a first-order lag (``lag_s``, 0 = none) and a speed
limit (``rate_deg_s``), then an optional second-order servo that follows the reference
(``servo_hz``, ``overshoot``: the fraction a step overshoots, 0 = critically damped).
"""

from __future__ import annotations

import functools
import math
from collections import deque

import msgspec
from msgspec import Struct

STEP_S = 0.01
"""Integration step (the simulator's physics step)."""


class ModeDynamics(Struct, frozen=True, forbid_unknown_fields=True):
    """One smoothing mode's response of one joint."""

    rate_deg_s: float = 90.0
    """Speed limit of the reference."""
    lag_s: float = 0.25
    """First-order time constant of the reference (0: none, the reference moves at the limit)."""
    dead_s: float = 0.0
    """Dead time between a command and the first motion."""
    servo_hz: float = 0.0
    """Natural frequency of a second-order servo after the reference (0: none)."""
    overshoot: float = 0.0
    """Step overshoot of that servo, 0..0.3 (0: critically damped)."""

    def problem(self) -> str | None:
        """What is out of range, or None."""
        figures = (self.rate_deg_s, self.lag_s, self.dead_s, self.servo_hz, self.overshoot)
        if not all(math.isfinite(x) for x in figures):
            return "figures must be finite"
        if not (1.0 <= self.rate_deg_s <= 1000.0 and 0.0 <= self.lag_s <= 5.0):
            return "need 1 <= rate_deg_s <= 1000 and 0 <= lag_s <= 5"
        if not (0.0 <= self.dead_s <= 1.0 and 0.0 <= self.servo_hz <= 20.0):
            return "need 0 <= dead_s <= 1 and 0 <= servo_hz <= 20"
        if not 0.0 <= self.overshoot <= 0.3:
            return "need 0 <= overshoot <= 0.3"
        return None


SIM_DEFAULT: dict[int, ModeDynamics] = {
    0: ModeDynamics(rate_deg_s=180.0, lag_s=0.05),
    1: ModeDynamics(rate_deg_s=90.0, lag_s=0.25),
}
"""The simulator's own smoothing (a 60 deg move takes about 1 s in mode 1; mode 0 tracks a
10 Hz stream closely). Also the detector's *uncalibrated* guess: untrusted."""


class ArmDynamics(Struct, frozen=True, forbid_unknown_fields=True):
    """Both modes of a joint (the simulator's ``sim_dynamics``, one joint of a calibration)."""

    mode0: ModeDynamics = msgspec.field(default_factory=lambda: SIM_DEFAULT[0])
    mode1: ModeDynamics = msgspec.field(default_factory=lambda: SIM_DEFAULT[1])

    def mode(self, mode: int) -> ModeDynamics:
        """The dynamics of smoothing ``mode`` (0 or 1)."""
        return self.mode0 if mode == 0 else self.mode1


@functools.lru_cache(maxsize=256)
def damping(overshoot: float) -> float:
    """The damping ratio of a second-order step response overshooting by ``overshoot``."""
    if overshoot <= 0.0:
        return 1.0
    log = math.log(overshoot)
    return -log / math.sqrt(math.pi**2 + log**2)


class JointResponse:
    """One joint's state under ``ModeDynamics``: the commanded target reaches the servo after
    the dead time of the command's mode; ``step`` integrates ``dt``."""

    def __init__(self, angle_deg: float) -> None:
        self.angle_deg = angle_deg
        self.reference_deg = angle_deg
        self.velocity_deg_s = 0.0
        self.target_deg = angle_deg
        self.mode = 1
        self._pending: deque[tuple[float, float, int]] = deque()  # (due s, target, mode)

    def command(self, target_deg: float, mode: int, now_s: float, dead_s: float) -> None:
        """A new target at ``now_s``; the servo sees it ``dead_s`` later (never before an earlier
        command: commands keep their order)."""
        due = now_s + dead_s
        if self._pending:
            due = max(due, self._pending[-1][0])
        if len(self._pending) >= 256:  # a stream faster than the dead time drains: keep newest
            self._pending.popleft()
        self._pending.append((due, target_deg, mode))

    def due(self, now_s: float) -> None:
        """Apply the commands whose dead time has passed by ``now_s``."""
        while self._pending and self._pending[0][0] <= now_s + 1e-9:
            _due, self.target_deg, self.mode = self._pending.popleft()

    def pending(self) -> bool:
        """Commands wait out their dead time."""
        return bool(self._pending)

    def at_rest(self) -> bool:
        """Nothing would change in a step."""
        return (
            not self._pending
            and self.angle_deg == self.target_deg == self.reference_deg
            and self.velocity_deg_s == 0.0
        )

    def hold(self, angle_deg: float) -> None:
        """The joint is at ``angle_deg``, not tracking (or blocked): reference and servo there."""
        self.angle_deg = self.reference_deg = angle_deg
        self.velocity_deg_s = 0.0

    def step(self, d: ModeDynamics, dt: float) -> float:
        """Integrate ``dt`` (at most ``STEP_S`` for a stable servo); returns the new angle."""
        self._integrate(d, dt, 1)
        return self.angle_deg

    def _integrate(self, d: ModeDynamics, dt: float, steps: int) -> None:
        """``steps`` steps of ``dt`` under ``d``, no command coming due on the way. The one copy
        of the response's arithmetic, and the hot loop of the simulator, the predictor and the
        calibration fit (millions of steps per fitted joint): figures hoisted out of the loop,
        state in locals, and it stops once at rest (a fixed point: no step changes anything)."""
        target, reference = self.target_deg, self.reference_deg
        angle, velocity = self.angle_deg, self.velocity_deg_s
        gain = 1.0 if d.lag_s <= 0.0 else 1.0 - math.exp(-dt / d.lag_s)
        limit = d.rate_deg_s * dt
        servo = d.servo_hz > 0.0
        wn = 2.0 * math.pi * d.servo_hz
        stiffness, friction = wn * wn, 2.0 * damping(d.overshoot) * wn
        for _ in range(steps):
            delta = (target - reference) * gain
            reference += limit if delta > limit else -limit if delta < -limit else delta
            if -1e-6 < target - reference < 1e-6:  # abs() without a call: this loop is hot
                reference = target
            if not servo:
                velocity = (reference - angle) / dt
                angle = reference
            else:
                velocity += (stiffness * (reference - angle) - friction * velocity) * dt
                angle += velocity * dt  # semi-implicit Euler: stable for wn * dt < 2
                still = -1e-6 < angle - reference < 1e-6 and -1e-4 < velocity < 1e-4
                if still and reference == target:
                    angle, velocity = reference, 0.0
            if angle == reference == target and velocity == 0.0:
                break
        self.reference_deg, self.angle_deg, self.velocity_deg_s = reference, angle, velocity

    def advance(self, dynamics: ArmDynamics, start_s: float, end_s: float) -> None:
        """Integrate from ``start_s`` to ``end_s`` in steps of at most ``STEP_S``; commands come
        due on the way, each step uses the dynamics of the mode in force."""
        span = end_s - start_s
        if span <= 0.0 or self.at_rest():
            return
        steps = min(int(span / STEP_S) + 1, 1000)
        dt = span / steps
        k = 0
        while k < steps:
            self.due(start_s + (k + 1) * dt)
            end = steps  # the steps before the next command comes due: one mode, no command
            if self._pending:
                end, head = k + 1, self._pending[0][0]
                while end < steps and head > start_s + (end + 1) * dt + 1e-9:
                    end += 1
            self._integrate(dynamics.mode(self.mode), dt, end - k)
            k = end


class SimDynamics(ArmDynamics, frozen=True, forbid_unknown_fields=True):
    """A simulated arm's response (inventory ``sim_dynamics``, per arm): both modes, and its
    feedback rate (uniform in ``feedback_hz``) with extra jitter (uniform 0..``jitter_s``)."""

    feedback_hz: tuple[float, float] = (9.0, 10.0)
    jitter_s: float = 0.0

    def problem(self) -> str | None:
        """What is out of range, or None."""
        for name, mode in (("mode0", self.mode0), ("mode1", self.mode1)):
            problem = mode.problem()
            if problem is not None:
                return f"{name}: {problem}"
        lo, hi = self.feedback_hz
        if not (1.0 <= lo <= hi <= 100.0 and 0.0 <= self.jitter_s <= 0.5):
            return "need 1 <= feedback_hz[0] <= feedback_hz[1] <= 100 and 0 <= jitter_s <= 0.5"
        return None

    def period_s(self) -> tuple[float, float]:
        """The range of feedback periods (seconds)."""
        return 1.0 / self.feedback_hz[1], 1.0 / self.feedback_hz[0]
