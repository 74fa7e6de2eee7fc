"""What a client that commands arms (the scripting API, the choreography player, the mirror)
knows of them: the latest joints, status and gripper contact of each.

``ArmWatch`` subscribes to the arms' joints, status and contact keys and keeps the latest of
each (a Zenoh callback only decodes, through the channel table, and stores under a lock: no
I/O, no Zenoh call). ``settle`` waits until arms are still (``fleet.d1.standstill``). The
heartbeat that makes the agents watch a commander is ``fleet.heartbeat``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import zenoh

from fleet.d1.limits import GRIPPER_JOINT
from fleet.d1.standstill import Standstill
from fleet.wire import keys, payloads
from fleet.wire import messages as m

STATUS_SILENT_S = 1.0
"""An arm whose agent published no status for this long has lost its link (status is 4 Hz)."""


@dataclass
class Latest:
    """The newest samples of one arm (``*_at``: monotonic time received)."""

    joints: m.Joints | None = None
    joints_at: float = 0.0
    status: m.ArmStatus | None = None
    status_at: float = 0.0
    contact: bool | None = None  # gripper grip per the agent's contact detector; None: no word


class ArmWatch:
    """Latest joints/status/contact of ``arms``; ``on_joints`` (optional) is called from the
    Zenoh thread with (arm, Joints) and must only hand off."""

    def __init__(
        self,
        session: zenoh.Session,
        space: keys.KeySpace,
        arms: Iterable[str],
        on_joints: Callable[[str, m.Joints], None] | None = None,
    ) -> None:
        self.space = space
        self.arms = list(arms)
        self.lock = threading.Lock()  # guards self._latest
        self._latest = {a: Latest() for a in self.arms}
        self._on_joints = on_joints
        self._subs = [
            session.declare_subscriber(space.all_arms(channel), self._on_sample)
            for channel in (keys.JOINTS, keys.STATUS, keys.CONTACT)
        ]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            key = self.space.parse_arm_key(str(sample.key_expr))
        except keys.KeyError_:
            return
        if key.arm not in self._latest:
            return
        try:
            payload = payloads.decode(key.channel, sample.payload.to_bytes())
        except payloads.PayloadError:
            return  # a foreign payload: the agent counts malformed data, not us
        now, arm = time.monotonic(), key.arm
        if isinstance(payload, m.Joints):
            with self.lock:
                self._latest[arm].joints, self._latest[arm].joints_at = payload, now
            if self._on_joints is not None:
                self._on_joints(arm, payload)
        elif isinstance(payload, m.ArmStatus):
            with self.lock:
                self._latest[arm].status, self._latest[arm].status_at = payload, now
        elif isinstance(payload, m.ContactEvent):
            contact = _gripper_contact(payload)
            if contact is not None:
                with self.lock:
                    self._latest[arm].contact = contact

    def latest(self, arm: str) -> Latest:
        """A copy of the newest samples of ``arm``."""
        with self.lock:
            got = self._latest[arm]
            return Latest(got.joints, got.joints_at, got.status, got.status_at, got.contact)

    def problem(self, arm: str, now_s: float) -> str | None:
        """Why ``arm`` must not be commanded now (stopped, link not ok, silent), or None."""
        got = self.latest(arm)
        return report_problem(f"arm {arm!r}", "status", got.status, got.status_at, now_s)

    def wait_ready(self, timeout_s: float, stop: threading.Event | None = None) -> str | None:
        """Wait (bounded; ``stop`` ends it) for every arm's joints and status; the first
        problem left, or None."""

        def problems(now: float) -> list[str]:
            found = [p for a in self.arms if (p := self.problem(a, now)) is not None]
            missing = [a for a in self.arms if self.latest(a).joints is None]
            if missing and not found:
                found = [f"no joints from arm {missing[0]!r} yet; is its agent running?"]
            return found

        return first_problem_left(problems, timeout_s, stop)

    def close(self) -> None:
        """Undeclare the subscriptions (idempotent)."""
        subs, self._subs = self._subs, []
        for sub in subs:
            sub.undeclare()


class UnitReport(Protocol):
    """What an agent says of its unit's stop and link (an arm's status, a device's state)."""

    @property
    def estopped(self) -> bool: ...
    @property
    def stop_reason(self) -> str | None: ...
    @property
    def link(self) -> str: ...


def report_problem(
    label: str,
    what: str,
    report: UnitReport | None,
    at_s: float,
    now_s: float,
    silent_s: float = STATUS_SILENT_S,
) -> str | None:
    """Why a unit (``label``: ``arm 'a1'``) must not be commanded by its newest ``report``
    (``what``: its name, received at ``at_s``): silent, stopped or link not ok; or None."""
    if report is None or now_s - at_s > silent_s:
        return f"{label} lost its link: no {what} from its agent for {silent_s:g} s"
    if report.estopped:
        return f"{label} is stopped ({report.stop_reason or 'protective stop'})"
    if report.link != "ok":
        return f"{label} lost its link (link {report.link})"
    return None


def first_problem_left(
    problems: Callable[[float], list[str]],
    timeout_s: float,
    stop: threading.Event | None = None,
) -> str | None:
    """Poll ``problems(now)`` (bounded by ``timeout_s``, and ended by ``stop``) until there are
    none; the first one left, or None."""
    deadline = time.monotonic() + timeout_s
    pause = stop or threading.Event()
    while True:
        now = time.monotonic()
        found = problems(now)
        if not found:
            return None
        if now >= deadline:
            return found[0]
        if pause.wait(0.05):
            return "stopped while waiting for the arms to be ready"


def _gripper_contact(event: m.ContactEvent) -> bool | None:
    """A gripper ``ContactEvent``: True for a confirmed grip, False when released or free,
    None for anything else (another joint, a suspicion: the last word stands)."""
    if event.joint != GRIPPER_JOINT:
        return None
    if event.state == "confirmed":
        return event.grip
    return False if event.state in ("released", "free") else None


def settle(
    watch: ArmWatch,
    arms: Sequence[str],
    goal: Mapping[str, tuple[float, ...]] | None,
    timeout_s: float,
) -> dict[str, tuple[float, ...]]:
    """Wait (bounded) until every arm is still (and within 0.8 deg of ``goal``); returns each
    arm's last pose."""
    deadline = time.monotonic() + timeout_s
    still = {a: Standstill() for a in arms}
    seen: dict[str, int] = {}
    poses: dict[str, tuple[float, ...]] = {}
    while time.monotonic() < deadline:
        for arm in arms:
            joints = watch.latest(arm).joints
            if joints is not None and seen.get(arm) != joints.seq:
                seen[arm] = joints.seq
                poses[arm] = tuple(joints.angles_deg)
                still[arm].add(poses[arm])
        if all(
            s.still and (goal is None or _spread(poses[a], goal[a]) < 0.8) for a, s in still.items()
        ):
            break
        time.sleep(0.05)
    return poses


def _spread(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return max(abs(x - y) for x, y in zip(a, b))
