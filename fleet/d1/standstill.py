"""When a D1 is still: the one definition, from its angle reports. Pure.

The agent confirms a stop with it (its ``still_ns`` is the first of the reports that agree: the
arm was still from then; the ack goes with the last), the choreography player and
the mirror wait for it before they hand an arm back, and the grip check asks it of the gripper.
At 10 Hz feedback three reports span about 0.3 s: long enough that a decelerating arm is not
taken for a still one, short enough that a stop is confirmed within half a second.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

STILL_SAMPLES = 3
"""Three consecutive angle reports (about 0.3 s) ..."""
STILL_TOLERANCE_DEG = 0.3
"""... within 0.3 deg of the first of them on every joint mean the arm is still."""


def is_still(reports: Sequence[Sequence[float]]) -> bool:
    """True when the last STILL_SAMPLES ``reports`` (each a report's angles, or one joint's as
    a 1-tuple) agree within STILL_TOLERANCE_DEG; False with fewer reports."""
    if len(reports) < STILL_SAMPLES:
        return False
    recent = list(reports)[-STILL_SAMPLES:]
    first = recent[0]
    return all(
        abs(a - b) <= STILL_TOLERANCE_DEG for sample in recent for a, b in zip(sample, first)
    )


@dataclass
class Standstill:
    """Detects standstill from the last few angle reports of one arm."""

    window: deque[tuple[float, ...]] = field(default_factory=lambda: deque(maxlen=STILL_SAMPLES))
    stamps: deque[int] = field(default_factory=lambda: deque(maxlen=STILL_SAMPLES))

    def add(self, angles_deg: Sequence[float], stamp_ns: int = 0) -> None:
        """Record one angle report (``stamp_ns``: when it was received)."""
        self.window.append(tuple(angles_deg))
        self.stamps.append(stamp_ns)

    def clear(self) -> None:
        """Forget history (a new stop starts a new observation)."""
        self.window.clear()
        self.stamps.clear()

    @property
    def still_since_ns(self) -> int | None:
        """When still: the stamp of the first report of the window, the one the later reports
        agree with (the arm was still from then on; the last report only confirms it)."""
        return self.stamps[0] if self.still else None

    @property
    def still(self) -> bool:
        """True when the last STILL_SAMPLES reports agree within STILL_TOLERANCE_DEG."""
        return is_still(self.window)
