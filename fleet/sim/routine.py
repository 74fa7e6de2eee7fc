"""The calibration routine played on a pure simulated arm (no transport): the benchmark and the
unit tests calibrate simulated arms this way; ``fleet calibrate`` plays the same plan on the
fleet. Feedback comes at the arm's own rate and jitter, with a little transport latency."""

from __future__ import annotations

import random

from fleet.contact.fit import SETTLE_TOLERANCE_DEG, StepRecord, plan
from fleet.d1 import protocol as p
from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.sim.model import SimArmModel

STEP_TIMEOUT_S = 6.0


def record_steps(model: SimArmModel, joint: int, rng: random.Random) -> list[StepRecord]:
    """Play the routine's steps for ``joint`` on ``model`` (from its current time and pose)."""
    now = model.time_s
    lo, hi = model.dynamics.period_s()
    records: list[StepRecord] = []
    for mode, target in plan(model.angles_deg[joint], JOINT_RANGE_DEG[joint]):
        pose = list(model.angles_deg)
        pose[joint] = target
        start = model.angles_deg[joint]
        model.advance(now)
        model.apply(p.encode_command(p.SetAllAngles(tuple(round(a, 2) for a in pose), mode), 1))
        record = StepRecord(mode, now, start, target)
        end = now + STEP_TIMEOUT_S
        still = 0
        while now < end and still < 3:
            now += rng.uniform(lo, hi) + rng.uniform(0.0, model.dynamics.jitter_s)
            model.advance(now)
            angle = model.angles_deg[joint]
            arrive = now + rng.uniform(0.0005, 0.003)
            previous = record.samples[-1][1] if record.samples else start
            record.samples.append((arrive, round(angle, 2)))
            near = abs(angle - target) < SETTLE_TOLERANCE_DEG
            still = still + 1 if near and abs(angle - previous) < 0.05 else 0
        records.append(record)
    return records
