"""Online sanity of method 5's model: after every move that completes in free
motion (the joint reached its target, no confirmed contact on the way) the detector records how
far the model was off during it. When the model disagrees with the arm on ``BAD_MOVES`` of the
last ``WINDOW`` free moves, at moments ``SAME_MOMENT_S`` apart, the detector stops trusting it
for this arm: method 5 may still raise suspicion but never confirms or force-limits (the robust
methods remain), and ``note`` says so (the agent's ``diag``).

A load spike that makes one report late (or a burst of them) puts every joint then moving
behind the model at that moment: several moves disagree at once, yet it is one event, not
sustained evidence, so disagreements at one moment count once. Trust returns with a new
calibration (or an agent restart), or once the model agreed with the arm on ``REEARN_MOVES``
free moves in a row: a right calibration judged during disturbances must not stay distrusted
for good, and a wrong one, off on most moves, never agrees that long. Pure.
"""

from __future__ import annotations

from collections import deque

WINDOW = 5
BAD_MOVES = 2
BAD_RATIO = 1.0
"""A free move disagrees when the model's residual passed method 5's tolerance on some sample:
the model alone would have suspected a contact where there was none."""
SAME_MOMENT_S = 0.5
"""Disagreements whose worst samples lie within this time of each other are one piece of
evidence (one late report, or a burst of late reports after a stall of up to this long)."""
REEARN_MOVES = 2 * WINDOW
"""Free moves in a row on which the model agreed with the arm that give a distrusted model its
trust back: twice the window that took it."""


class ModelSanity:
    """The model's record in free motion, for one arm."""

    def __init__(self, calibrated: bool) -> None:
        self.calibrated = calibrated
        self.revoked: str | None = None
        self.free_moves = 0
        self.last_error_deg: float | None = None
        # Per recent free move: when its worst disagreeing sample was, None when it agreed.
        self._recent: deque[float | None] = deque(maxlen=WINDOW)
        self._agreed_in_a_row = 0
        # joint -> (max ratio, max residual, time of the max ratio)
        self._moves: dict[int, tuple[float, float, float]] = {}

    @property
    def trusted(self) -> bool:
        """Whether method 5 may confirm (and force-limit) on this arm."""
        return self.calibrated and self.revoked is None

    def note(self) -> str:
        """What the detector's model is worth, in one phrase (for ``diag`` and the log)."""
        if not self.calibrated:
            return "uncalibrated: model untrusted, robust methods only (run fleet calibrate)"
        if self.revoked is not None:
            return self.revoked
        return "calibrated: model trusted"

    def start(self, joint: int) -> None:
        """A commanded move of ``joint`` begins (a move already under way goes on)."""
        self._moves.setdefault(joint, (0.0, 0.0, 0.0))

    def sample(self, joint: int, residual_deg: float, tolerance_deg: float, now_s: float) -> None:
        """One sample of a move at ``now_s``: the model's residual and method 5's tolerance."""
        move = self._moves.get(joint)
        if move is not None:
            ratio = abs(residual_deg) / tolerance_deg
            worst_s = now_s if ratio > move[0] else move[2]
            self._moves[joint] = (max(move[0], ratio), max(move[1], abs(residual_deg)), worst_s)

    def discard(self, joint: int) -> None:
        """The move met a contact (or the joint stopped tracking): it tells nothing."""
        self._moves.pop(joint, None)

    def _moments(self) -> int:
        """How many separate moments the recent disagreements happened at."""
        times = sorted(t for t in self._recent if t is not None)
        return sum(1 for k, t in enumerate(times) if k == 0 or t - times[k - 1] > SAME_MOMENT_S)

    def complete(self, joint: int) -> str | None:
        """``joint`` reached its target in free motion; returns a note when this revokes trust
        or gives it back."""
        move = self._moves.pop(joint, None)
        if move is None:
            return None
        ratio, error, worst_s = move
        self.free_moves += 1
        self.last_error_deg = round(error, 2)
        disagreed = ratio > BAD_RATIO
        self._recent.append(worst_s if disagreed else None)
        self._agreed_in_a_row = 0 if disagreed else self._agreed_in_a_row + 1
        if self.revoked is not None and self._agreed_in_a_row >= REEARN_MOVES:
            self.revoked = None
            self._recent.clear()  # the evidence that revoked it is outweighed: start afresh
            return (
                f"model trusted again: it agreed with the arm on {REEARN_MOVES} free moves in a row"
            )
        moments = self._moments()
        if self.trusted and moments >= BAD_MOVES:
            self.revoked = (
                f"model untrusted: off by up to {error:.1f} deg in free motion on "
                f"{sum(t is not None for t in self._recent)} of the last {len(self._recent)} "
                f"moves, at {moments} moments (joint {joint}); robust methods only until the "
                f"arm is calibrated again or the model agrees on {REEARN_MOVES} free moves in "
                "a row"
            )
            return self.revoked
        return None
