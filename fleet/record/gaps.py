"""Gaps in the joints by ``seq``: how many samples of each arm never reached the recorder.

``Joints.seq`` counts the samples an agent relayed for one arm (1, 2, 3, ...). Joints travel
with congestion control DROP (latest-wins state: a slow subscriber must never stall the relay),
so a sample can be dropped by the agent's Zenoh session, by the router or on the way to the
recorder, and nothing tells the subscriber. The holes in ``seq`` do. Pure: fed seqs, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ArmGaps:
    """One arm's joints as seen by ``seq``."""

    received: int = 0
    missing: int = 0
    """Samples skipped by ``seq`` between two received ones (the holes, summed)."""
    holes: int = 0
    restarts: int = 0
    """``seq`` went back (or repeated): the agent restarted and counts from 1 again. Samples
    lost around a restart cannot be counted."""
    first: int | None = None
    last: int | None = None

    def add(self, seq: int) -> None:
        """One received sample's ``seq``."""
        self.received += 1
        if self.last is None:
            self.first = seq
        elif seq > self.last + 1:
            self.missing += seq - self.last - 1
            self.holes += 1
        elif seq <= self.last:
            self.restarts += 1
        self.last = seq

    @property
    def missing_fraction(self) -> float:
        """Missing over expected (received + missing); 0 when nothing was expected."""
        expected = self.received + self.missing
        return self.missing / expected if expected else 0.0

    def describe(self) -> str:
        """``300 received, 3 missing (1.0 %) in 2 holes``, plus restarts if any."""
        text = f"{self.received} received, {self.missing} missing"
        if self.missing:
            text += f" ({100 * self.missing_fraction:.1f} %) in {self.holes} hole"
            text += "s" if self.holes != 1 else ""
        if self.restarts:
            text += f", seq restarted {self.restarts} time" + ("s" if self.restarts != 1 else "")
        return text


class SeqGaps:
    """Every arm's ``ArmGaps``."""

    def __init__(self) -> None:
        self.arms: dict[str, ArmGaps] = {}

    def add(self, arm: str, seq: int) -> None:
        """One received joints sample of ``arm``."""
        self.arms.setdefault(arm, ArmGaps()).add(seq)

    def missing(self) -> dict[str, int]:
        """``{arm: samples missing by seq}``."""
        return {arm: gaps.missing for arm, gaps in self.arms.items()}

    def describe(self) -> str:
        """One line per arm, for ``fleet record``'s summary."""
        return "\n".join(f"  {arm}: {g.describe()}" for arm, g in sorted(self.arms.items()))
