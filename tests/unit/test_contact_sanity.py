"""The online sanity of method 5's model: a right calibration is not distrusted for good by one
load spike (late reports put every moving joint behind the model at once), a wrong one still
is, and a distrusted model earns its trust back only by agreeing with the arm for long."""

from __future__ import annotations

import random

import msgspec
import pytest

from bench import contact as bc
from fleet.contact.calibration import Calibration
from fleet.contact.config import ContactConfig
from fleet.contact.detector import ContactDetector
from fleet.contact.dynamics import SimDynamics
from fleet.contact.feed import feed_command
from fleet.contact.sanity import BAD_MOVES, REEARN_MOVES, ModelSanity
from fleet.d1 import protocol as p
from fleet.sim.model import SimArmModel

PERIOD_S = 0.1
"""The arm's feedback period (10 Hz)."""


@pytest.fixture(scope="module")
def right() -> Calibration:
    """The default simulated arm's own calibration (joint 0's fit on every joint)."""
    one = bc.calibrate(SimDynamics(), 1, joints=(0,))
    joints = [msgspec.structs.replace(one.joints[0], joint=j) for j in range(7)]
    return msgspec.structs.replace(one, joints=joints)


def _play(calibration: Calibration, spike_at_s: float | None, spike_s: float) -> ContactDetector:
    """Six free moves of three joints at once, 2.5 s each, on the simulated arm. A load spike
    of ``spike_s`` at ``spike_at_s``: the reports made meanwhile arrive together at its end."""
    model = SimArmModel(angles_deg=[0.0] * 7, target_deg=[0.0] * 7, rng=random.Random(1))
    detector = ContactDetector(ContactConfig(), calibration=calibration)
    detector.on_targets(dict.fromkeys(range(7), 0.0), 1, 0.0)
    t = 0.0
    for move in range(6):
        sign = 1.0 if move % 2 == 0 else -1.0
        command = p.SetAllAngles((20.0 * sign, 15.0 * sign, 10.0 * sign, 0, 0, 0, 30.0), 1)
        model.advance(t + 0.002)
        feed_command(detector, command, t)
        model.apply(p.encode_command(command, 1))
        for _ in range(25):
            t += PERIOD_S
            model.advance(t)
            arrive = t + 0.002
            if spike_at_s is not None and spike_at_s <= t < spike_at_s + spike_s:
                arrive = spike_at_s + spike_s
            report = model.joint_report()
            assert report is not None
            detector.on_angles(report.angles_deg, arrive)
    return detector


@pytest.mark.parametrize("spike_s", [0.1, 0.15, 0.3, 1.0])
@pytest.mark.parametrize("spike_at_s", [2.6, 2.8, 3.0, 3.2])
def test_one_load_spike_does_not_distrust_a_right_calibration(
    right: Calibration, spike_at_s: float, spike_s: float
) -> None:
    # Early in the second move (three joints moving): each joint's move disagreed, and two
    # disagreeing moves distrusted the model for good (reproduced at 0.1-1.0 s spikes).
    detector = _play(right, spike_at_s, spike_s)
    assert detector.sanity.trusted, detector.sanity.note()
    assert detector.sanity.free_moves >= 15


def test_without_a_spike_the_right_calibration_is_trusted(right: Calibration) -> None:
    assert _play(right, None, 0.0).sanity.trusted


def _judge(sanity: ModelSanity, joint: int, ratio: float, at_s: float) -> str | None:
    """One free move of ``joint`` whose worst sample was ``ratio`` tolerances off at ``at_s``."""
    sanity.start(joint)
    sanity.sample(joint, ratio, 1.0, at_s)
    return sanity.complete(joint)


def test_disagreements_at_separate_moments_still_distrust_the_model() -> None:
    sanity = ModelSanity(calibrated=True)
    assert _judge(sanity, 0, 1.5, 1.0) is None
    assert _judge(sanity, 1, 1.5, 1.2) is None  # the same moment: one piece of evidence
    assert sanity.trusted
    note = _judge(sanity, 0, 1.5, 4.0)
    assert note is not None and "untrusted" in note and not sanity.trusted
    assert f"at {BAD_MOVES} moments" in note


def test_a_distrusted_model_earns_trust_back_only_by_agreeing_long_enough() -> None:
    sanity = ModelSanity(calibrated=True)
    _judge(sanity, 0, 2.0, 1.0)
    _judge(sanity, 0, 2.0, 3.0)
    assert not sanity.trusted
    t = 5.0
    for _ in range(REEARN_MOVES - 1):  # one short of it, then one more disagreement
        t += 2.0
        assert _judge(sanity, 0, 0.5, t) is None
    assert _judge(sanity, 0, 1.5, t + 2.0) is None and not sanity.trusted
    notes = []
    for k in range(REEARN_MOVES):
        notes.append(_judge(sanity, k % 3, 0.5, t + 4.0 + 2.0 * k))
    assert notes[:-1] == [None] * (REEARN_MOVES - 1)
    assert notes[-1] is not None and "trusted again" in notes[-1]
    assert sanity.trusted and sanity.note() == "calibrated: model trusted"


def test_an_uncalibrated_model_is_never_trusted_by_agreeing() -> None:
    sanity = ModelSanity(calibrated=False)
    for k in range(2 * REEARN_MOVES):
        _judge(sanity, 0, 0.1, float(k))
    assert not sanity.trusted
