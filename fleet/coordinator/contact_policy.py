"""The coordinator's contact table, policies and collision memory. Pure, injected clock.

Policies (the plan's safety section), for a CONFIRMED contact on an arm joint:
- the arm was holding still (``commanded`` False, phase ``idle``): something hit it -> stop
  that arm (a protective stop on ``arm/<arm>/estop``);
- phase ``lift``: a snag while lifting -> stop;
- phase ``approach``/``grasp``/``move`` (moving under a command): stop the motion (hold) and
  report; the first contact at a place backs off ``backoff_deg`` and retries once, a repeat
  there holds and reports the joint blocked;
- the gripper: a confirmed contact while closing is a grip -> report; otherwise hold.
Phases come from the task (``MultiArmRequest.phase``, for ``phase_s``); without one an arm is
``move`` while commanded and ``idle`` otherwise.

Collision memory: contacts are remembered per (arm, joint, place) for ``expire_s``; a target
past a place is refused only after ``avoid_after`` contacts there (the old memory banned an
angle after one contact, which was too aggressive). ``clear()`` forgets (a workspace change).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from fleet.wire import messages as m

Phase = Literal["idle", "move", "approach", "grasp", "lift"]
ActionKind = Literal["estop", "hold", "backoff_retry", "report"]
GRIPPER = 6


@dataclass(frozen=True)
class Action:
    """What the coordinator does about a contact (``service`` performs it, off the Zenoh
    thread). ``backoff_deg``/``retry_deg``: angles for ``backoff_retry``."""

    kind: ActionKind
    arm: str
    joint: int
    reason: str
    backoff_deg: float | None = None
    retry_deg: float | None = None


@dataclass
class ContactRow:
    """The latest contact event of one joint, the phase it happened in and what was done."""

    event: m.ContactEvent
    phase: Phase
    action: ActionKind | None
    received_s: float


@dataclass
class _Place:
    angle_deg: float
    direction: int  # +1: the joint was pushing towards higher angles
    times: list[float] = field(default_factory=list)


MAX_PLACES = 32
"""Places remembered per (arm, joint); a new place beyond this forgets the one met longest ago."""
MAX_TIMES = 16
"""Contacts remembered per place (``avoid_after`` needs only a few)."""


class CollisionMemory:
    """Where joints met obstacles: places within ``place_deg`` of each other are one place.
    Bounded: at most MAX_PLACES places per joint, MAX_TIMES contacts per place."""

    def __init__(self, place_deg: float = 3.0, expire_s: float = 600.0, avoid_after: int = 3):
        self.place_deg, self.expire_s, self.avoid_after = place_deg, expire_s, avoid_after
        self._places: dict[tuple[str, int], list[_Place]] = {}

    def record(self, arm: str, joint: int, angle_deg: float, direction: int, now: float) -> int:
        """Remember a contact; returns how many contacts this place has within ``expire_s``."""
        self._expire(now)
        places = self._places.setdefault((arm, joint), [])
        for place in places:
            if place.direction == direction and abs(place.angle_deg - angle_deg) <= self.place_deg:
                place.times.append(now)
                del place.times[:-MAX_TIMES]
                return len(place.times)
        places.append(_Place(angle_deg, direction, [now]))
        if len(places) > MAX_PLACES:
            places.remove(min(places, key=lambda p: p.times[-1]))
        return 1

    def avoided(self, arm: str, joint: int, target_deg: float, now: float) -> float | None:
        """The avoided place that ``target_deg`` would reach past, or None."""
        self._expire(now)
        for place in self._places.get((arm, joint), []):
            past = place.direction * (target_deg - place.angle_deg) > -self.place_deg
            if len(place.times) >= self.avoid_after and past:
                return place.angle_deg
        return None

    def clear(self, arm: str | None = None) -> None:
        """Forget every place (of ``arm``, or of the fleet)."""
        for key in [k for k in self._places if arm is None or k[0] == arm]:
            del self._places[key]

    def _expire(self, now: float) -> None:
        for places in self._places.values():
            for place in places:
                place.times = [t for t in place.times if now - t <= self.expire_s]
            places[:] = [p for p in places if p.times]


class ContactPolicy:
    """The fleet contact table and the decisions made on it."""

    def __init__(self, memory: CollisionMemory | None = None, backoff_deg: float = 5.0):
        self.memory = memory or CollisionMemory()
        self.backoff_deg = backoff_deg
        self.table: dict[str, dict[int, ContactRow]] = {}
        self._phases: dict[str, tuple[Phase, float]] = {}

    def set_phase(self, arm: str, phase: Phase, now: float, for_s: float = 30.0) -> None:
        """The task says what ``arm``'s current motion is for, valid for ``for_s``."""
        self._phases[arm] = (phase, now + for_s)

    def phase_of(self, arm: str, commanded: bool, now: float) -> Phase:
        """The declared phase, or ``move``/``idle`` from whether the joint was commanded."""
        declared = self._phases.get(arm)
        if declared is not None and now <= declared[1] and commanded:
            return declared[0]
        return "move" if commanded else "idle"

    def in_contact(self, arm: str) -> bool:
        """True while any joint of ``arm`` is in a confirmed contact."""
        return any(r.event.state == "confirmed" for r in self.table.get(arm, {}).values())

    def on_event(self, arm: str, event: m.ContactEvent, now: float) -> list[Action]:
        """Record ``event`` in the table; returns what to do about it."""
        phase = self.phase_of(arm, event.commanded, now)
        row = ContactRow(event, phase, None, now)
        self.table.setdefault(arm, {})[event.joint] = row
        if event.state != "confirmed":
            return []
        action = self._decide(arm, event, phase, now)
        row.action = action.kind
        return [action]

    def _decide(self, arm: str, event: m.ContactEvent, phase: Phase, now: float) -> Action:
        joint, where = event.joint, f"joint {event.joint} at {event.measured_deg} deg"
        if joint == GRIPPER:
            if event.grip:
                return Action("report", arm, joint, f"grip confirmed ({where})")
            return Action("hold", arm, joint, f"gripper contact while not closing ({where})")
        if phase == "idle":
            return Action("estop", arm, joint, f"unexpected contact while idle on {where}")
        if phase == "lift":
            return Action("estop", arm, joint, f"snag while lifting on {where}")
        direction = 1 if event.error_deg > 0 else -1
        angle = event.measured_deg if event.measured_deg is not None else 0.0
        count = self.memory.record(arm, joint, angle, direction, now)
        if count == 1 and event.target_deg is not None:
            return Action(
                "backoff_retry",
                arm,
                joint,
                f"contact while {phase} on {where}: backing off and retrying once",
                backoff_deg=angle - direction * self.backoff_deg,
                retry_deg=event.target_deg,
            )
        return Action("hold", arm, joint, f"blocked while {phase} on {where} ({count} contacts)")
