"""The arm dynamics the contact benchmark runs on: named families spanning every
plausible D1 (speed limits 20-180 deg/s, first-order lags 0.03-0.5 s, second-order servos up to
10 % overshoot, dead time up to 0.1 s, feedback 8-12 Hz with jitter, modes 0 and 1 unlike each
other) and seeded random draws over the same space. The detector is never tuned to one of them:
the goals hold on every family."""

from __future__ import annotations

import random

from fleet.contact.dynamics import ModeDynamics as M
from fleet.contact.dynamics import SimDynamics

NAMED: dict[str, SimDynamics] = {
    "sim default": SimDynamics(),
    "rate 60 (issue 13)": SimDynamics(mode0=M(60.0, 0.0), mode1=M(60.0, 0.0)),
    "rate 20": SimDynamics(mode0=M(20.0, 0.0), mode1=M(20.0, 0.0)),
    "rate 180": SimDynamics(mode0=M(180.0, 0.0), mode1=M(180.0, 0.0)),
    "lag 0.03": SimDynamics(mode0=M(180.0, 0.03), mode1=M(180.0, 0.03)),
    "lag 0.5": SimDynamics(mode0=M(90.0, 0.5), mode1=M(60.0, 0.5)),
    "overshoot 10%": SimDynamics(
        mode0=M(120.0, 0.03, servo_hz=2.5, overshoot=0.1),
        mode1=M(90.0, 0.1, servo_hz=1.5, overshoot=0.1),
    ),
    "dead 0.1": SimDynamics(mode0=M(120.0, 0.1, dead_s=0.1), mode1=M(60.0, 0.3, dead_s=0.1)),
    "feedback 8-12 Hz": SimDynamics(feedback_hz=(8.0, 12.0), jitter_s=0.04),
    "modes swapped": SimDynamics(mode0=M(30.0, 0.4), mode1=M(180.0, 0.03)),
}


def random_family(rng: random.Random) -> SimDynamics:
    """One draw over the plausible space (each mode on its own)."""

    def mode() -> M:
        servo = rng.random() < 0.4
        return M(
            rate_deg_s=round(rng.uniform(20.0, 180.0), 1),
            lag_s=round(rng.choice([0.0, rng.uniform(0.03, 0.5)]), 3),
            dead_s=round(rng.uniform(0.0, 0.1), 3),
            servo_hz=round(rng.uniform(1.5, 6.0), 2) if servo else 0.0,
            overshoot=round(rng.uniform(0.0, 0.1), 3) if servo else 0.0,
        )

    lo = rng.uniform(8.0, 10.0)
    return SimDynamics(
        mode0=mode(),
        mode1=mode(),
        feedback_hz=(round(lo, 1), round(rng.uniform(lo, 12.0), 1)),
        jitter_s=round(rng.uniform(0.0, 0.04), 3),
    )


def families(seed: int = 7, draws: int = 4) -> dict[str, SimDynamics]:
    """The named families and ``draws`` seeded random ones."""
    rng = random.Random(seed)
    return NAMED | {f"random {k + 1}": random_family(rng) for k in range(draws)}
