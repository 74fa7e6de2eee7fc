"""Online sanity of method 5's model: after every move that completes in free
motion (the joint reached its target, no confirmed contact on the way) the detector records how
far the model was off during it. When the model disagrees with the arm on ``BAD_MOVES`` of the
last ``WINDOW`` free moves, the detector stops trusting it for this arm: method 5 may still raise
suspicion but never confirms or force-limits (the robust methods remain), and ``note`` says so
(the agent's ``diag``). Trust returns only with a new calibration (or an agent restart). Pure.
"""

from __future__ import annotations

from collections import deque

WINDOW = 5
BAD_MOVES = 2
BAD_RATIO = 1.0
"""A free move disagrees when the model's residual passed method 5's tolerance on some sample:
the model alone would have suspected a contact where there was none."""


class ModelSanity:
    """The model's record in free motion, for one arm."""

    def __init__(self, calibrated: bool) -> None:
        self.calibrated = calibrated
        self.revoked: str | None = None
        self.free_moves = 0
        self.last_error_deg: float | None = None
        self._recent: deque[bool] = deque(maxlen=WINDOW)
        self._moves: dict[int, tuple[float, float]] = {}  # joint -> (max ratio, max residual)

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
        self._moves.setdefault(joint, (0.0, 0.0))

    def sample(self, joint: int, residual_deg: float, tolerance_deg: float) -> None:
        """One sample of a move: the model's residual and method 5's tolerance there."""
        move = self._moves.get(joint)
        if move is not None:
            ratio = abs(residual_deg) / tolerance_deg
            self._moves[joint] = (max(move[0], ratio), max(move[1], abs(residual_deg)))

    def discard(self, joint: int) -> None:
        """The move met a contact (or the joint stopped tracking): it tells nothing."""
        self._moves.pop(joint, None)

    def complete(self, joint: int) -> str | None:
        """``joint`` reached its target in free motion; returns a note when this revokes trust."""
        move = self._moves.pop(joint, None)
        if move is None:
            return None
        ratio, error = move
        self.free_moves += 1
        self.last_error_deg = round(error, 2)
        self._recent.append(ratio > BAD_RATIO)
        if self.trusted and sum(self._recent) >= BAD_MOVES:
            self.revoked = (
                f"model untrusted: off by up to {error:.1f} deg in free motion on "
                f"{sum(self._recent)} of the last {len(self._recent)} moves (joint {joint}); "
                "robust methods only until the arm is calibrated again"
            )
            return self.revoked
        return None
