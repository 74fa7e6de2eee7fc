"""Method 5 with a calibrated, trusted model (issue 13, calibrated goals): the benchmark's onset
label, the model's timing allowance, corroboration before a model-only confirmation (and so
before a force limit), and the fit's error beyond report timing. Pure, injected clock."""

from __future__ import annotations

import random

import pytest

from bench import contact as bc
from bench.contact_families import NAMED
from fleet.contact.calibration import Calibration, JointCalibration
from fleet.contact.config import ContactConfig
from fleet.contact.detector import ContactDetector, ContactState
from fleet.contact.dynamics import ArmDynamics, ModeDynamics, SimDynamics
from fleet.contact.fit import fit, timing_rms
from fleet.contact.predictor import SmoothingPredictor
from fleet.d1 import protocol as p
from fleet.sim.model import SimArmModel
from fleet.sim.obstacles import Obstacle
from fleet.sim.routine import record_steps

RATE = ModeDynamics(rate_deg_s=60.0, lag_s=0.0)


def _calibrated(mode: ModeDynamics = RATE, rms: float = 0.05) -> ContactDetector:
    joints = [JointCalibration(j, mode, mode, rms) for j in range(7)]
    calibration = Calibration(arm="a1", stamp_ns=1, joints=joints)
    return ContactDetector(ContactConfig(methods=["model"]), calibration=calibration)


def _moving(target_deg: float | None) -> ContactDetector:
    """A calibrated detector of an arm resting at 0, joint 0 sent to ``target_deg`` at 0 s."""
    det = _calibrated()
    det.on_targets(dict.fromkeys(range(7), 0.0), 1, 0.0)
    det.on_angles((0.0,) * 7, 0.0)
    if target_deg is not None:
        det.on_targets({0: target_deg}, None, 0.0)
    return det


def _confirmed(det: ContactDetector, samples: list[tuple[float, float]]) -> list[float]:
    """Feed joint 0's angles; the times joint 0 became confirmed (and force-limited)."""
    out = []
    for stamp, angle in samples:
        report = det.on_angles((angle,) + (0.0,) * 6, stamp)
        out += [stamp for c in report.changes if c.state is ContactState.CONFIRMED]
    return out


def test_the_onset_of_a_hunting_stall_is_its_first_blocked_step() -> None:
    # Servo hunting lifts the joint off the wall and restarts the push counter: the label used
    # to be the last restart (0.4 s late), so a detection in time counted as a false alarm
    # before the touch plus a missed stall.
    model = SimArmModel(angles_deg=[0.0] * 7, target_deg=[0.0] * 7, rng=random.Random(1))
    model.faults.obstacles[0] = Obstacle(10.0, 0.0, hunting_deg=1.0)
    model.apply(p.encode_command(p.SetJointAngle(0, 40.0), 1))
    first, restarts, previous = None, 0, 0.0
    for k in range(1, 300):
        model.advance(k * 0.01)
        pushing = model.faults.obstacles[0].pushing_s
        if first is None and pushing > 0:
            first = k * 0.01 - pushing
        restarts += pushing < previous
        previous = pushing
    assert first is not None and restarts > 0
    assert model.faults.obstacles[0].met_s == pytest.approx(first, abs=0.011)
    ep = next(e for e in bc.episodes(7) if e.name == "stall-j4-mode0-49")
    out = bc.run(ep, ContactConfig(), NAMED["rate 60 (issue 13)"], None)
    assert out.onset_s is not None and out.onset_s < 0.8  # it meets the wall at ~0.76 s


def test_the_model_allows_for_its_travel_over_the_timing_window() -> None:
    # A fast rate-limited step that ends just before a report: the model's speed is 0 at the
    # report, but a report stamped 40 ms late may show the joint that much short.
    fast = ArmDynamics(ModeDynamics(180.0, 0.0), ModeDynamics(180.0, 0.0))
    predictor = SmoothingPredictor(1, [fast])
    predictor.advance(0.0)
    predictor.resync(0, 0.0)
    predictor.set_target(0, 10.0)
    predictor.advance(0.07, lookback_s=0.04)  # arrived at 0.056
    assert predictor.velocity_deg_s(0) == 0.0
    assert predictor.travel_deg[0] == pytest.approx(180.0 * 0.026, abs=0.2)


def test_a_model_a_little_off_never_confirms_alone() -> None:
    # The arm moves 5 % slower than its calibration says over a long move: the lag passes the
    # tolerance slowly, sample after sample (confirmed on two samples before corroboration).
    det = _moving(120.0)
    samples = [(0.1 * k, min(120.0, 57.0 * 0.1 * k)) for k in range(1, 30)]
    assert _confirmed(det, samples) == []


def test_a_late_first_report_of_a_move_does_not_confirm() -> None:
    # The first report after a command, taken at 50 ms, is stamped 200 ms late: the joint looks
    # as if it had hardly started (12 deg behind, grown by more than 0.7 of the model's way).
    det = _moving(60.0)
    samples = [(0.25, 3.0)] + [(0.1 * k, min(60.0, 6.0 * k)) for k in range(3, 14)]
    assert _confirmed(det, samples) == []


def test_a_joint_that_stops_mid_move_is_confirmed_on_one_sample_and_force_limited() -> None:
    det = _moving(60.0)
    samples = [(0.1, 6.0), (0.2, 12.0), (0.3, 14.0), (0.4, 14.0)]
    limits: dict[int, float] = {}
    confirmed = []
    for stamp, angle in samples:
        report = det.on_angles((angle,) + (0.0,) * 6, stamp)
        confirmed += [stamp for c in report.changes if c.state is ContactState.CONFIRMED]
        limits |= report.force_limit
    # 0.3: 6 deg short of the model (tolerance 1 + 60 x 0.04 + 0.15), grown by 4 of the
    # model's 6: not yet corroborated (share 0.67 < 0.7); 0.4: grown by all 6, confirmed.
    assert confirmed == [0.4]
    assert limits == {0: 14.0}


def test_a_held_joint_pushed_away_is_confirmed_once_past_the_tolerance() -> None:
    det = _moving(None)
    pushed = [(0.1 * k, -0.5 * k) for k in range(1, 6)]
    # tolerance 1 + 3 x 0.05: past it at 0.3 s (1.5 deg), growing 0.5 a sample: confirmed.
    assert _confirmed(det, pushed) == [pytest.approx(0.3)]


def test_the_fits_error_beyond_report_timing_is_what_the_model_adds() -> None:
    # Feedback 8-12 Hz with 40 ms jitter: the plain RMS counts the late stamps at speed as
    # model error (and the detector allows for them already); the timing RMS does not.
    jittery = SimDynamics(feedback_hz=(8.0, 12.0), jitter_s=0.04)
    model = SimArmModel(dynamics=jittery, rng=random.Random(5))
    records = record_steps(model, 0, random.Random(5))
    mode1 = [r for r in records if r.mode == 1]
    fitted, rms = fit(mode1)
    excess = timing_rms(fitted, mode1, 0.08)
    assert excess < 0.5 * rms
    calibration = JointCalibration(0, fitted, fitted, rms, timing_rms_deg=excess)
    assert calibration.error_deg() == excess
    assert JointCalibration(0, fitted, fitted, rms).error_deg() == rms  # files before it
