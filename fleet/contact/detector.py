"""The contact detector: position-only feedback -> per-joint contact states. Pure.

Feed it every target the agent sends (``on_targets``), every angle report (``on_angles``) and
every status report (``on_status``), each with its time (monotonic seconds). Per joint it keeps
a ring buffer of samples, evaluates the five methods (``methods.py``) and runs the state
machine FREE -> SUSPECTED -> CONFIRMED -> RELEASED -> FREE:

- FREE/RELEASED -> SUSPECTED: an enabled method fires;
- SUSPECTED -> CONFIRMED: an enabled method fired continuously for ``confirm_s``
  (``status`` confirms at once); SUSPECTED -> FREE: nothing fires any more;
- CONFIRMED -> RELEASED: nothing fires and the tracking error stays below ``release_deg`` for
  ``release_s`` (hysteresis); RELEASED -> FREE after another ``release_s`` of quiet.

A joint that does not track (unloaded, unpowered, stopped with unload/power_off) is never in
contact: moving it by hand is not a contact. The gripper uses its own thresholds; a confirmed
gripper contact while closing is a grip.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass, field

from fleet.contact import methods as mth
from fleet.contact.config import ContactConfig, Method, Thresholds
from fleet.contact.predictor import SmoothingPredictor

GRIPPER = 6


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


@dataclass
class _Joint:
    thresholds: Thresholds
    samples: deque[tuple[float, float]]
    target: float | None = None
    target_s: float = 0.0
    commanded: bool = False
    torque_on: bool = True
    since: dict[str, float] = field(default_factory=dict)
    state: ContactState = ContactState.FREE
    quiet_s: float | None = None
    limited: bool = False
    onsets: dict[str, list[float]] = field(default_factory=dict)


class ContactDetector:
    """Contact detection for one arm of ``joints`` wire joints (the last is the gripper)."""

    def __init__(self, config: ContactConfig, joints: int = 7) -> None:
        self.config = config
        self.methods: frozenset[str] = frozenset(config.methods)
        self._joints = [
            _Joint(config.for_joint(j), deque(maxlen=config.buffer_size)) for j in range(joints)
        ]
        self._model = SmoothingPredictor(joints)
        self._arm_tracking = True
        self._error_flag = False

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
        self._model.advance(now_s)
        report = Report()
        errors: dict[int, float] = {}
        for j, angle in enumerate(angles_deg[: len(self._joints)]):
            joint = self._joints[j]
            joint.samples.append((now_s, angle))
            if self._model.predicted[j] is None:
                self._model.resync(j, angle)  # the first sample anchors the prediction
            if not (self._arm_tracking and joint.torque_on) or joint.target is None:
                self._model.resync(j, angle)
                joint.since.clear()
                self._to(report, j, ContactState.FREE, "not tracking", 0.0, 0.0, now_s)
                continue
            errors[j] = joint.target - angle
        status_joint = self._status_joint(errors, angles_deg)
        for j, error in errors.items():
            fired = self._evaluate(j, error, angles_deg[j], now_s, j == status_joint)
            self._step(report, j, error, fired, now_s)
            joint = self._joints[j]
            limit = joint.thresholds.force_limit_deg
            if (
                joint.state is ContactState.CONFIRMED
                and limit is not None
                and abs(error) > limit
                and not joint.limited
            ):
                joint.limited = True
                report.force_limit[j] = angles_deg[j]
        return report

    def _status_joint(self, errors: dict[int, float], angles: tuple[float, ...]) -> int | None:
        """Method 3 names no joint: blame the arm joint furthest from where it should be."""
        if not self._error_flag or not errors:
            return None
        scores = {}
        for j, error in errors.items():
            residual = self._model.residual(j, angles[j]) or 0.0
            scores[j] = max(abs(error), abs(residual)) / self._joints[j].thresholds.release_deg
        best = max(scores, key=lambda j: scores[j])
        return best if scores[best] > 1.0 else None

    def _evaluate(
        self, j: int, error: float, angle: float, now_s: float, status: bool
    ) -> set[Method]:
        joint = self._joints[j]
        t = joint.thresholds
        fires: dict[Method, bool] = {
            "tracking": mth.tracking(error, t),
            "stall": mth.stall(error, joint.samples, t),
            "status": status,
            "oscillation": mth.oscillation(joint.samples, joint.target_s, now_s, t),
            "model": mth.model(self._model.residual(j, angle), self._model.velocity_deg_s(j), t),
        }
        fired: set[Method] = set()
        for method, on in fires.items():
            if not on:
                joint.since.pop(method, None)
                continue
            started = joint.since.setdefault(method, now_s)
            fired.add(method)
            times = joint.onsets.setdefault(method, [])
            new_run = not times or times[-1] < started
            if new_run and self._is_confirmed(joint, method, now_s):
                times.append(now_s)
        return fired

    def _is_confirmed(self, joint: _Joint, method: str, now_s: float) -> bool:
        since = joint.since.get(method)
        if since is None:
            return False
        return method == "status" or now_s - since >= joint.thresholds.confirm_s

    def _step(self, report: Report, j: int, error: float, fired: set[Method], now_s: float) -> None:
        joint = self._joints[j]
        active = sorted(m for m in fired if m in self.methods)
        confirmed = [m for m in active if self._is_confirmed(joint, m, now_s)]
        confidence = round(len(fired - {"status"}) / 4.0, 2) if fired else 0.0
        if "status" in fired:
            confidence = 1.0
        state = joint.state
        if confirmed and state is not ContactState.CONFIRMED:
            if state in (ContactState.FREE, ContactState.RELEASED) and confirmed != ["status"]:
                self._to(report, j, ContactState.SUSPECTED, confirmed[0], error, 0.5, now_s)
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
            and joint.target < measured
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
