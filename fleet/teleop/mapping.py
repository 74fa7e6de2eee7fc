"""Per-follower joint mapping and limits for ``fleet mirror``. Pure.

A follower copies the leader joint by joint; ``--invert a2:0,5`` negates joints 0 and 5 for a
mirror-image set-up (two arms facing each other), ``--limit a2:1=-45:45`` narrows a joint's range
(always inside the D1's own ranges). A mapped angle outside the range is clamped to it: the
follower stops at its limit while the leader goes on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG


class MappingError(ValueError):
    """A ``--invert`` or ``--limit`` option that cannot be used; the message names it."""


@dataclass(frozen=True)
class FollowerMap:
    """How one follower turns the leader's angles into its own targets."""

    arm: str
    sign: tuple[int, ...] = (1,) * JOINT_COUNT
    range_deg: tuple[tuple[float, float], ...] = JOINT_RANGE_DEG

    def apply(self, leader_deg: Sequence[float]) -> list[float]:
        """The follower's targets for one leader sample (degrees, clamped to the range)."""
        return [
            min(max(s * a, low), high)
            for s, a, (low, high) in zip(self.sign, leader_deg, self.range_deg, strict=True)
        ]


def _split(option: str, spec: str, followers: Sequence[str]) -> tuple[str, str]:
    arm, sep, rest = spec.partition(":")
    if not sep or arm not in followers:
        raise MappingError(f"{option} {spec!r}: expected FOLLOWER:..., followers are {followers}")
    return arm, rest


def _joint(option: str, spec: str, text: str) -> int:
    if not text.strip().isdigit() or not 0 <= int(text) < JOINT_COUNT:
        raise MappingError(f"{option} {spec!r}: {text!r} is not a joint 0..{JOINT_COUNT - 1}")
    return int(text)


def parse_mappings(
    followers: Sequence[str], inverts: Sequence[str] = (), limits: Sequence[str] = ()
) -> list[FollowerMap]:
    """Build each follower's map from ``--invert ARM:J,J`` and ``--limit ARM:J=LO:HI``."""
    signs = {f: [1] * JOINT_COUNT for f in followers}
    ranges = {f: list(JOINT_RANGE_DEG) for f in followers}
    for spec in inverts:
        arm, rest = _split("--invert", spec, followers)
        for text in rest.split(","):
            signs[arm][_joint("--invert", spec, text)] = -1
    for spec in limits:
        arm, rest = _split("--limit", spec, followers)
        joint_text, _, bounds = rest.partition("=")
        joint = _joint("--limit", spec, joint_text)
        try:
            low, high = (float(v) for v in bounds.split(":"))
        except ValueError:
            raise MappingError(f"--limit {spec!r}: expected ARM:J=LO:HI in degrees") from None
        hard_low, hard_high = JOINT_RANGE_DEG[joint]
        if not hard_low <= low < high <= hard_high:
            raise MappingError(
                f"--limit {spec!r}: {low:g}:{high:g} must be increasing and inside joint "
                f"{joint}'s range {hard_low:g}:{hard_high:g}"
            )
        ranges[arm][joint] = (low, high)
    return [FollowerMap(f, tuple(signs[f]), tuple(ranges[f])) for f in dict.fromkeys(followers)]
