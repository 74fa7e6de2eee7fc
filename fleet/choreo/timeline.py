"""The choreography timeline: where every arm should be now. Pure, with an injected clock.

``Timeline.tick(now_s, facts)`` returns a ``Frame``: each arm's target (interpolated between
keyframes with the step's easing), the step being played, the time left, and whether the script
is done or failed (a wait timed out). The player feeds it measured facts (angles, grip) and
streams the targets; tests feed it a fake clock and fake facts.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from fleet.choreo.script import Move, Pose, Script, Wait

EASE: dict[str, Callable[[float], float]] = {
    "linear": lambda u: u,
    "ease_in": lambda u: u * u,
    "ease_out": lambda u: 1.0 - (1.0 - u) * (1.0 - u),
    "ease_in_out": lambda u: u * u * (3.0 - 2.0 * u),  # smoothstep: still at both ends
}
PEAK_SPEED_FACTOR: dict[str, float] = {
    "linear": 1.0,
    "ease_in": 2.0,
    "ease_out": 2.0,
    "ease_in_out": 1.5,
}
"""Peak speed of an eased segment over its average speed (the easing's largest slope)."""


def max_error_deg(a: Pose, b: Pose) -> float:
    """The largest per-joint difference between two poses."""
    return max(abs(x - y) for x, y in zip(a, b, strict=True))


@dataclass(frozen=True)
class ArmFacts:
    """What the player measured of one arm (``None``: no sample yet)."""

    angles_deg: Pose | None = None
    gripped: bool = False


@dataclass(frozen=True)
class Frame:
    """The timeline at one instant."""

    targets: dict[str, Pose]
    iteration: int
    step_index: int
    label: str
    kind: str  # "move", "wait", "done" or "failed"
    step_left_s: float
    total_left_s: float | None  # None: loops forever
    finished_keyframes: list[int] = field(default_factory=list)
    error: str | None = None


class Timeline:
    """Plays ``script`` from ``start_poses`` (every arm involved, measured before the start)."""

    def __init__(self, script: Script, start_poses: Mapping[str, Pose]) -> None:
        missing = [a for a in script.arms if a not in start_poses]
        if missing:
            raise ValueError(f"no start pose for {', '.join(missing)}")
        self.script = script
        self.poses: dict[str, Pose] = {a: tuple(start_poses[a]) for a in script.arms}
        self._from: dict[str, Pose] = dict(self.poses)
        self.iteration = 0
        self.index = 0
        self.step_start_s = 0.0
        self.started = False
        self.finished: str | None = None  # "done" or "failed"
        self.error: str | None = None

    def start(self, now_s: float) -> None:
        """The synchronized start: step 0 begins at ``now_s``."""
        self.step_start_s = now_s
        self.started = True

    # ------------------------------------------------------------------ ticking

    def tick(self, now_s: float, facts: Mapping[str, ArmFacts]) -> Frame:
        """Advance to ``now_s`` (completed steps, satisfied waits) and return the frame."""
        if not self.started:
            self.start(now_s)
        done: list[int] = []
        while self.finished is None and self._complete(now_s, facts, done):
            self._advance()
        return self._frame(now_s, done)

    def _complete(self, now_s: float, facts: Mapping[str, ArmFacts], done: list[int]) -> bool:
        """True (and the end of the step is booked) when the current step is over."""
        step = self.script.steps[self.index]
        if isinstance(step, Move):
            end = self.step_start_s + step.duration_s
            if now_s < end:
                return False
            self.poses.update(step.poses)
            done.append(self.index)
            self.step_start_s = end  # exact: no drift from tick jitter
            return True
        if self._satisfied(step, facts):
            self.step_start_s = max(now_s, self.step_start_s)
            return True
        if now_s - self.step_start_s > step.timeout_s:
            self.finished, self.error = "failed", self._timeout_message(step, facts)
        return False

    def _satisfied(self, step: Wait, facts: Mapping[str, ArmFacts]) -> bool:
        for arm in step.arms:
            fact = facts.get(arm, ArmFacts())
            if step.condition == "grip":
                if not fact.gripped:
                    return False
            elif fact.angles_deg is None or (
                max_error_deg(fact.angles_deg, self.poses[arm]) > self.script.reach_tolerance_deg
            ):
                return False
        return True

    def _timeout_message(self, step: Wait, facts: Mapping[str, ArmFacts]) -> str:
        late = []
        for arm in step.arms:
            fact = facts.get(arm, ArmFacts())
            if step.condition == "grip" and not fact.gripped:
                late.append(f"{arm} (no grip confirmed)")
            elif step.condition == "reached":
                error = (
                    "no angles"
                    if fact.angles_deg is None
                    else f"{max_error_deg(fact.angles_deg, self.poses[arm]):.1f} deg off"
                )
                late.append(f"{arm} ({error})")
        late_text = ", ".join(late) or "?"
        return (
            f"step {self.index} (wait {step.condition}) timed out after {step.timeout_s:g} s: "
            f"{late_text}"
        )

    def _advance(self) -> None:
        self._from = dict(self.poses)
        self.index += 1
        if self.index < len(self.script.steps):
            return
        loops = self.script.loops
        if loops == 0 or self.iteration + 1 < loops:
            self.iteration += 1
            self.index = 0
        else:
            self.index = len(self.script.steps) - 1
            self.finished = "done"

    # ------------------------------------------------------------------ frames

    def _frame(self, now_s: float, done: list[int]) -> Frame:
        step = self.script.steps[self.index]
        targets = dict(self.poses)
        step_left = 0.0
        if self.finished is None and isinstance(step, Move):
            u = min(1.0, max(0.0, (now_s - self.step_start_s) / step.duration_s))
            eased = EASE[step.easing](u)
            for arm, goal in step.poses.items():
                start = self._from[arm]
                targets[arm] = tuple(a + (b - a) * eased for a, b in zip(start, goal))
            step_left = max(0.0, step.duration_s - (now_s - self.step_start_s))
        elif self.finished is None:
            step_left = max(0.0, step.timeout_s - (now_s - self.step_start_s))
        kind = self.finished or ("move" if isinstance(step, Move) else "wait")
        return Frame(
            targets=targets,
            iteration=self.iteration,
            step_index=self.index,
            label=step.label or f"step {self.index}",
            kind=kind,
            step_left_s=step_left,
            total_left_s=self._total_left(step_left),
            finished_keyframes=done,
            error=self.error,
        )

    def _total_left(self, step_left: float) -> float | None:
        if self.finished is not None:
            return 0.0
        if self.script.loops == 0:
            return None
        later = sum(
            s.duration_s for s in self.script.steps[self.index + 1 :] if isinstance(s, Move)
        )
        whole = (self.script.loops - self.iteration - 1) * self.script.iteration_s
        running = step_left if isinstance(self.script.steps[self.index], Move) else 0.0
        return running + later + whole


def next_tick(tick: int, elapsed_s: float, period_s: float) -> int:
    """The tick to wait for after ``tick``, ``elapsed_s`` into the play: the next one still
    ahead. Ticks skip, never catch up: the ticks a descheduled player missed, run back to
    back, each appended a target to the player's path window within microseconds, flushing
    from it the target the arm was at."""
    return max(tick + 1, math.floor(elapsed_s / period_s) + 1)


class PlayClock:
    """The timeline's time: the monotonic clock less the time the player lost to stalls.

    A player descheduled for 0.25-0.4 s (a load spike on its host) woke to a timeline that
    had moved on: its next target lay 15-35 deg further along the path, the arm leapt there
    at its top speed, and a feedback sample caught between the two targets read 12-17 deg
    "off its path" (the play aborted). A tick later than one period resumes the timeline
    where that tick was due instead: every arm holds its last target through the stall and
    goes on from it, all of them together (one clock), and no target is ever a leap."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lost_s = 0.0
        """The time lost to stalls so far (the play ends that much later)."""

    def play_time(self, due_s: float, now_s: float) -> float:
        """The timeline's time for a tick due at ``due_s`` and run at ``now_s`` (monotonic)."""
        if now_s - due_s > self.period_s:
            self.lost_s += now_s - due_s
        return now_s - self.lost_s
