"""The contact detector: position-only feedback -> per-joint contact states. Pure.

Feed it every target the agent sends (``on_targets``), every angle report (``on_angles``) and
every status report (``on_status``), each with its time (monotonic seconds). Per joint it keeps
a ring buffer of samples, evaluates the five methods (``methods.py``) and runs the state
machine FREE -> SUSPECTED -> CONFIRMED -> RELEASED -> FREE:

- FREE/RELEASED -> SUSPECTED: an enabled method fires;
- SUSPECTED -> CONFIRMED: an enabled method fired continuously for ``confirm_s``
  (``status`` confirms at once; a trusted model on one corroborated sample, see
  ``CORROBORATE_SHARE``); SUSPECTED -> FREE: nothing fires any more;
- CONFIRMED -> RELEASED: nothing fires and the tracking error stays below ``release_deg`` for
  ``release_s`` (hysteresis); RELEASED -> FREE after another ``release_s`` of quiet.

A joint that does not track (unloaded, unpowered, stopped with unload/power_off) is never in
contact: moving it by hand is not a contact. The gripper uses its own thresholds; a confirmed
gripper contact while closing is a grip.

Trust: method 5 needs a model of this arm's response. Without a calibration of the
joint (``Calibration``), or once the online sanity check (``sanity.py``) found the model off in
free motion, method 5 may raise suspicion but never confirms; a contact is confirmed only by a
method trustworthy for this arm, and only such a contact is force-limited.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass, field

from fleet.contact import methods as mth
from fleet.contact.calibration import Calibration
from fleet.contact.config import ContactConfig, Method, Thresholds
from fleet.contact.predictor import DEFAULT_DYNAMICS, SmoothingPredictor
from fleet.contact.sanity import ModelSanity

GRIPPER = 6
CORROBORATE_SHARE = 0.7
"""Method 5 confirms on a sample whose lag behind the model grew, since the previous sample, by
at least this share of the model's own progress (the joint made under 30 % of the way the model
made: it stopped) ..."""
STILL_RATIO = 2.0
"""... or it confirms when the joint is this many tolerances behind it on two samples running
and makes no way (``_held_back``)."""
CORROBORATE_MIN_DEG = 0.3
"""... and by at least this much (3x the feedback noise: a held joint pushed away). A model
that is merely off (a speed a few percent wrong, a report stamped late, a servo ringing
differently) shifts the lag slowly or by less than the model moved, never like this."""


class ContactState(str, enum.Enum):
    """Per-joint contact state."""

    FREE = "free"
    SUSPECTED = "suspected"
    CONFIRMED = "confirmed"
    RELEASED = "released"


@dataclass(frozen=True)
class ContactChange:
    """A joint changed state. ``method`` is what caused it (``quiet`` for a release)."""

    joint: int
    state: ContactState
    method: str
    error_deg: float
    confidence: float
    stamp_s: float
    target_deg: float | None
    measured_deg: float
    commanded: bool
    grip: bool = False


@dataclass
class Report:
    """What one angle report produced: state changes, and joints to force-limit (the agent
    retracts each one's target to the measured angle)."""

    changes: list[ContactChange] = field(default_factory=list)
    force_limit: dict[int, float] = field(default_factory=dict)
    model_note: str | None = None
    """Set when this report made the detector stop trusting its model, or trust it again
    (online sanity)."""


@dataclass
class _Joint:
    thresholds: Thresholds
    samples: deque[tuple[float, float]]
    errors: deque[tuple[float, float]]
    target: float | None = None
    target_s: float = 0.0
    commanded: bool = False
    torque_on: bool = True
    since: dict[str, float] = field(default_factory=dict)
    state: ContactState = ContactState.FREE
    quiet_s: float | None = None
    limited: bool = False
    onsets: dict[str, list[float]] = field(default_factory=dict)
    demand: int = 0
    """The side the joint was sent to (+1/-1), 0 once it settled on its target."""
    confirmed_by: str = ""
    model_ratio: float = 0.0
    """How far behind the model the joint is, in multiples of method 5's tolerance."""
    model_last: tuple[int, float, float, float] | None = None
    """(prediction epoch, predicted angle, lag, the model's progress before it) at the previous
    sample."""
    corroborated: bool = False
    """The newest sample's lag grew like a contact's (``CORROBORATE_*``)."""


class ContactDetector:
    """Contact detection for one arm of ``joints`` wire joints (the last is the gripper)."""

    def __init__(
        self,
        config: ContactConfig,
        joints: int = 7,
        calibration: Calibration | None = None,
        gripper_closing_sign: float = -1.0,
    ) -> None:
        """``gripper_closing_sign``: -1 when closing the gripper lowers ``angle6`` (the default
        reading, 0 closed), +1 when it raises it (the arm's inventory says which)."""
        self.config = config
        self.gripper_closing_sign = gripper_closing_sign
        self.methods: frozenset[str] = frozenset(config.methods)
        size = config.buffer_size
        self._joints = [
            _Joint(config.for_joint(j), deque(maxlen=size), deque(maxlen=size))
            for j in range(joints)
        ]
        self._model = SmoothingPredictor(joints)
        self._calibrated: frozenset[int] = frozenset()
        self.sanity = ModelSanity(calibrated=False)
        self.set_calibration(calibration)
        self._arm_tracking = True
        self._error_flag = False

    def set_calibration(self, calibration: Calibration | None) -> None:
        """Use ``calibration`` for method 5's model (None: uncalibrated, model untrusted); the
        online sanity check starts afresh."""
        joints = len(self._joints)
        fitted = [None if calibration is None else calibration.joint(j) for j in range(joints)]
        dynamics = [DEFAULT_DYNAMICS if c is None else c.dynamics() for c in fitted]
        old = self._model
        self._model = SmoothingPredictor(joints, dynamics)
        self._model.mode, self._model.time_s = old.mode, old.time_s
        for j, joint in enumerate(self._joints):
            if joint.target is not None:
                self._model.set_target(j, joint.target)
            if joint.samples:
                self._model.resync(j, joint.samples[-1][1])
        self._calibrated = frozenset(j for j, c in enumerate(fitted) if c is not None)
        # The model's tolerance also covers the calibration's own error (3 x its RMS).
        self._slack = [0.0 if c is None else 3.0 * c.error_deg() for c in fitted]
        self._timing_s = 0.0 if calibration is None else calibration.feedback_jitter_s
        timing = (self.config.arm.timing_tolerance_s, self.config.gripper.timing_tolerance_s)
        self._lookback_s = max(*timing, self._timing_s)
        self.sanity = ModelSanity(calibrated=bool(self._calibrated))

    def trusted(self, joint: int, method: str) -> bool:
        """Whether ``method`` may confirm a contact on ``joint`` (and so force-limit it)."""
        if method != "model":
            return True
        return joint in self._calibrated and self.sanity.trusted

    # ------------------------------------------------------------------ inputs

    def on_targets(self, targets_deg: dict[int, float], mode: int | None, now_s: float) -> None:
        """Targets sent to the arm at ``now_s``; ``mode`` is the smoothing mode of a ``1/2``
        command (None for ``1/1``, which keeps the arm's mode)."""
        self._model.advance(now_s)
        if mode is not None:
            self._model.mode = mode
        for j, target in targets_deg.items():
            joint = self._joints[j]
            measured = joint.samples[-1][1] if joint.samples else None
            joint.commanded = measured is not None and abs(target - measured) > (
                joint.thresholds.release_deg
            )
            if joint.commanded and measured is not None:
                joint.demand = 1 if target > measured else -1
                self.sanity.start(j)
            joint.target, joint.target_s, joint.limited = target, now_s, False
            if measured is not None and joint.state in (
                ContactState.CONFIRMED,
                ContactState.RELEASED,
            ):
                # In contact the joint is still: restart the prediction where it rests. (In free
                # motion the last sample is up to a cycle old: it would be the wrong anchor.)
                self._model.resync(j, measured)
            self._model.set_target(j, target)

    def on_torque(self, joint: int | None, on: bool) -> None:
        """Torque of one joint (or all) switched by a command the agent sent."""
        for j in range(len(self._joints)) if joint is None else (joint,):
            self._joints[j].torque_on = on

    def on_status(
        self, error: bool | None, enabled: bool | None, powered: bool | None, now_s: float
    ) -> None:
        """The arm's status report (``error_status``, ``enable_status``, ``power_status``)."""
        self._error_flag = bool(error)
        self._arm_tracking = enabled is not False and powered is not False

    def set_tracking(self, tracking: bool) -> None:
        """Whether the arm tracks its targets at all (False while stopped by unload/power off)."""
        self._arm_tracking = tracking

    # ------------------------------------------------------------------ queries

    def state(self, joint: int) -> ContactState:
        """The contact state of ``joint``."""
        return self._joints[joint].state

    def confirmations(self, joint: int) -> dict[str, list[float]]:
        """Per method (enabled or not), the times it became confirmed on ``joint``: each
        continuous run of firing counts once (the benchmark's per-method figures)."""
        return {m: list(times) for m, times in self._joints[joint].onsets.items()}

    # ------------------------------------------------------------------ the core

    def on_angles(self, angles_deg: tuple[float, ...], now_s: float) -> Report:
        """One angle report: evaluate every joint; returns the state changes."""
        self._model.advance(now_s, self._lookback_s)
        report = Report()
        errors: dict[int, float] = {}
        predicted = self._model.predicted
        for j, angle in enumerate(angles_deg[: len(self._joints)]):
            joint = self._joints[j]
            joint.samples.append((now_s, angle))
            if predicted[j] is None:
                self._model.resync(j, angle)  # the first sample anchors the prediction
            if not (self._arm_tracking and joint.torque_on) or joint.target is None:
                joint.errors.append((now_s, 0.0))
                self._model.resync(j, angle)
                self.sanity.discard(j)
                joint.since.clear()
                self._to(report, j, ContactState.FREE, "not tracking", 0.0, 0.0, now_s)
                continue
            errors[j] = joint.target - angle
            joint.errors.append((now_s, errors[j]))
        status_joint = self._status_joint(errors, angles_deg)
        for j, error in errors.items():
            fired = self._evaluate(j, error, angles_deg[j], now_s, j == status_joint)
            self._step(report, j, error, fired, now_s)
            joint = self._joints[j]
            limit = joint.thresholds.force_limit_deg
            if (
                joint.state is ContactState.CONFIRMED
                and self.trusted(j, joint.confirmed_by)
                and (joint.confirmed_by != "model" or self._held_back(joint, error))
                and limit is not None
                and abs(error) > limit
                and not joint.limited
            ):
                joint.limited = True
                report.force_limit[j] = angles_deg[j]
            self._check_model(report, j, error, angles_deg[j], now_s)
        return report

    @staticmethod
    def _held_back(joint: _Joint, error: float) -> bool:
        """The joint is not making way towards its target (it moves slower than
        ``stall_velocity_deg_s``): what the force limit asks of a contact only the model saw,
        so that a calibration gone wrong can never retract a free move's target."""
        speed = mth.velocity_deg_s(joint.samples)
        return speed is None or speed * (1.0 if error > 0 else -1.0) < (
            joint.thresholds.stall_velocity_deg_s
        )

    def _check_model(
        self, report: Report, j: int, error: float, angle: float, now_s: float
    ) -> None:
        """Online sanity: the model's error during a move, judged when the move ends free."""
        joint = self._joints[j]
        t = joint.thresholds
        # A move is evidence about the model unless something else confirmed a contact on the
        # way (or the force limit moved its target): a move the model alone called a contact
        # that then reached its target was a false alarm of the model, and counts against it.
        robust = joint.state is ContactState.CONFIRMED and joint.confirmed_by != "model"
        if robust or joint.limited:
            self.sanity.discard(j)
            return
        lag = mth.behind(self._model.residual(j, angle), joint.demand)
        if lag is not None:
            self.sanity.sample(j, max(0.0, lag), self._tolerance(j), now_s)
        speed = mth.velocity_deg_s(joint.samples)
        settled = abs(error) < t.release_deg and (
            speed is None or abs(speed) < t.stall_velocity_deg_s
        )
        if settled:
            joint.demand = 0
            note = self.sanity.complete(j)
            if note is not None:
                report.model_note = note

    def _status_joint(self, errors: dict[int, float], angles: tuple[float, ...]) -> int | None:
        """Method 3 names no joint: blame the arm joint furthest from where it should be."""
        if not self._error_flag or not errors:
            return None
        scores = {}
        for j, error in errors.items():
            residual = (
                (self._model.residual(j, angles[j]) or 0.0) if self.trusted(j, "model") else 0.0
            )
            scores[j] = max(abs(error), abs(residual)) / self._joints[j].thresholds.release_deg
        best = max(scores, key=lambda j: scores[j])
        return best if scores[best] > 1.0 else None

    def _evaluate(
        self, j: int, error: float, angle: float, now_s: float, status: bool
    ) -> set[Method]:
        joint = self._joints[j]
        t = joint.thresholds
        # Near its target, only error_status and a trusted model may fire (ringing, noise).
        near = abs(error) < t.suspect_deg
        fires: dict[Method, bool] = {
            "tracking": mth.tracking(error, t),
            "stall": mth.stall(joint.samples, joint.errors, joint.demand, t),
            "status": status,
            "oscillation": mth.oscillation(joint.samples, joint.errors, joint.target_s, now_s, t),
            "model": self._model_fires(joint, j, angle),
        }
        fired: set[Method] = set()
        for method, on in fires.items():
            if not on or (near and method != "status" and not self.trusted(j, method)):
                joint.since.pop(method, None)
                continue
            started = joint.since.setdefault(method, now_s)
            fired.add(method)
            times = joint.onsets.setdefault(method, [])
            new_run = not times or times[-1] < started
            if new_run and self._is_confirmed(joint, method, now_s):
                times.append(now_s)
        return fired

    def _tolerance(self, j: int) -> float:
        """Method 5's tolerance on ``j`` now: its base, the model's travel over the timing
        window (a late report), and the calibration's own error."""
        t = self._joints[j].thresholds
        speed, travel = self._model.velocity_deg_s(j), self._model.travel_deg[j]
        return mth.model_tolerance(speed, t, self._timing_s, travel) + self._slack[j]

    def _model_fires(self, joint: _Joint, j: int, angle: float) -> bool:
        lag = mth.behind(self._model.residual(j, angle), joint.demand)
        tolerance = self._tolerance(j)
        joint.model_ratio = 0.0 if lag is None else lag / tolerance
        predicted = self._model.predicted[j]
        epoch = self._model.epochs[j]
        last, joint.corroborated = joint.model_last, False
        if lag is None or predicted is None:
            joint.model_last = None
            return False
        progress = 0.0
        if last is not None and last[0] == epoch:
            progress = (predicted - last[1]) * joint.demand if joint.demand else 0.0
            growth = lag - last[2]
            # A move's first interval tells nothing: a report stamped late, or a dead time a
            # little longer than the fit's, looks like a joint that did not start. So the model
            # must already have been under way on the interval before (a held joint: no move).
            under_way = joint.demand == 0 or last[3] > CORROBORATE_MIN_DEG
            joint.corroborated = under_way and growth >= max(
                CORROBORATE_MIN_DEG, CORROBORATE_SHARE * max(progress, 0.0)
            )
        joint.model_last = (epoch, predicted, lag, progress)
        return lag > tolerance

    def _is_confirmed(self, joint: _Joint, method: str, now_s: float) -> bool:
        since = joint.since.get(method)
        if since is None:
            return False
        if method == "model":
            # One sample, corroborated: the joint stopped (or is pushed) while the model says it
            # moves (or holds); a joint moving to its target is not confirmed by the model
            # within ``suspect_deg`` of it (a servo ringing otherwise than the fit).
            # Or, once the model has arrived: far behind it (``STILL_RATIO`` tolerances) on two
            # samples running while the joint makes no way (a fast move that met the wall as
            # the model reached its target: the lag no longer grows).
            error = abs(joint.errors[-1][1]) if joint.errors else 0.0
            near = joint.demand != 0 and error < joint.thresholds.suspect_deg
            still = (
                now_s - since >= joint.thresholds.confirm_s
                and joint.model_ratio >= STILL_RATIO
                and self._held_back(joint, joint.errors[-1][1])
            )
            return (joint.corroborated or still) and not near
        return method == "status" or now_s - since >= joint.thresholds.confirm_s

    def _step(self, report: Report, j: int, error: float, fired: set[Method], now_s: float) -> None:
        joint = self._joints[j]
        active = sorted(m for m in fired if m in self.methods)
        confirmed = [
            m for m in active if self._is_confirmed(joint, m, now_s) and self.trusted(j, m)
        ]
        confidence = round(len(fired - {"status"}) / 4.0, 2) if fired else 0.0
        if "status" in fired:
            confidence = 1.0
        state = joint.state
        if confirmed and state is not ContactState.CONFIRMED:
            if state in (ContactState.FREE, ContactState.RELEASED) and confirmed != ["status"]:
                self._to(report, j, ContactState.SUSPECTED, confirmed[0], error, 0.5, now_s)
            joint.confirmed_by = confirmed[0]
            self._to(report, j, ContactState.CONFIRMED, confirmed[0], error, confidence, now_s)
        elif active and state in (ContactState.FREE, ContactState.RELEASED):
            self._to(report, j, ContactState.SUSPECTED, active[0], error, confidence / 2, now_s)
        elif not active and state is ContactState.SUSPECTED:
            self._to(report, j, ContactState.FREE, "quiet", error, 0.0, now_s)
        elif state in (ContactState.CONFIRMED, ContactState.RELEASED):
            quiet = not active and abs(error) < joint.thresholds.release_deg
            if not quiet:
                joint.quiet_s = None
            elif joint.quiet_s is None:
                joint.quiet_s = now_s
            elif now_s - joint.quiet_s >= joint.thresholds.release_s:
                nxt = (
                    ContactState.RELEASED if state is ContactState.CONFIRMED else ContactState.FREE
                )
                self._to(report, j, nxt, "quiet", error, 0.0, now_s)

    def _to(
        self,
        report: Report,
        j: int,
        state: ContactState,
        method: str,
        error: float,
        confidence: float,
        now_s: float,
    ) -> None:
        joint = self._joints[j]
        if joint.state is state:
            return
        joint.state, joint.quiet_s = state, None
        measured = joint.samples[-1][1]
        if state is ContactState.RELEASED:
            self._model.resync(j, measured)
        grip = (
            j == GRIPPER
            and state is ContactState.CONFIRMED
            and joint.target is not None
            and (joint.target - measured) * self.gripper_closing_sign > 0  # it was closing
        )
        report.changes.append(
            ContactChange(
                joint=j,
                state=state,
                method=method,
                error_deg=round(error, 2),
                confidence=confidence,
                stamp_s=now_s,
                target_deg=joint.target,
                measured_deg=measured,
                commanded=joint.commanded,
                grip=grip,
            )
        )
