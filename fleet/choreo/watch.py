"""What a streaming commander (the choreography player, the mirror) needs to know of its arms,
and the heartbeat that makes the agents watch them.

``ArmWatch`` subscribes to the arms' joints, status and contact keys and keeps the latest of
each (a Zenoh callback only decodes and stores under a lock: no I/O, no Zenoh call).
``Liveness`` publishes a ``Heartbeat`` with the commander's id on ``heartbeat/<principal>`` at
10 Hz on its own thread: agents treat any heartbeat publisher as a coordinator, so an arm moved
by this commander is held by its agent when the commander dies.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import zenoh

from fleet.client import JSON, STOP_QOS
from fleet.d1.limits import GRIPPER_JOINT
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import encode

log = logging.getLogger("fleet.choreo")

HEARTBEAT_PERIOD_S = 0.1
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
        data, now = sample.payload.to_bytes(), time.monotonic()
        try:
            if key.channel == keys.JOINTS:
                joints = payloads.JOINTS.decode(data)
                with self.lock:
                    self._latest[key.arm].joints, self._latest[key.arm].joints_at = joints, now
                if self._on_joints is not None:
                    self._on_joints(key.arm, joints)
            elif key.channel == keys.STATUS:
                status = payloads.STATUS.decode(data)
                with self.lock:
                    self._latest[key.arm].status, self._latest[key.arm].status_at = status, now
            elif key.channel == keys.CONTACT:
                contact = _contact_of(data)
                if contact is not None:
                    with self.lock:
                        self._latest[key.arm].contact = contact
        except payloads.PayloadError:
            return  # a foreign payload: the agent counts malformed data, not us

    def latest(self, arm: str) -> Latest:
        """A copy of the newest samples of ``arm``."""
        with self.lock:
            got = self._latest[arm]
            return Latest(got.joints, got.joints_at, got.status, got.status_at, got.contact)

    def problem(self, arm: str, now_s: float) -> str | None:
        """Why ``arm`` must not be commanded now (stopped, link not ok, silent), or None."""
        got = self.latest(arm)
        status = got.status
        if status is None or now_s - got.status_at > STATUS_SILENT_S:
            return f"arm {arm!r} lost its link: no status from its agent for {STATUS_SILENT_S:g} s"
        if status.estopped:
            return f"arm {arm!r} is stopped ({status.stop_reason or 'protective stop'})"
        if status.link != "ok":
            return f"arm {arm!r} lost its link (link {status.link})"
        return None

    def wait_ready(self, timeout_s: float) -> str | None:
        """Wait (bounded) for every arm's joints and status; the first problem left, or None."""
        deadline = time.monotonic() + timeout_s
        while True:
            now = time.monotonic()
            problems = [p for a in self.arms if (p := self.problem(a, now)) is not None]
            missing = [a for a in self.arms if self.latest(a).joints is None]
            if missing and not problems:
                problems = [f"no joints from arm {missing[0]!r} yet; is its agent running?"]
            if not problems or now >= deadline:
                return problems[0] if problems else None
            time.sleep(0.05)

    def close(self) -> None:
        """Undeclare the subscriptions (idempotent)."""
        subs, self._subs = self._subs, []
        for sub in subs:
            sub.undeclare()


def _contact_of(data: bytes) -> bool | None:
    """A gripper ``ContactEvent``: True for a confirmed grip, False when released or free,
    None for anything else (another joint, a suspicion: the last word stands)."""
    event = payloads.CONTACT.decode(data)
    if event.joint != GRIPPER_JOINT:
        return None
    if event.state == "confirmed":
        return event.grip
    return False if event.state in ("released", "free") else None


class Liveness:
    """A Heartbeat publisher for commander ``owner`` (10 Hz, own thread). A context manager."""

    def __init__(
        self, session: zenoh.Session, space: keys.KeySpace, owner: str, principal: str
    ) -> None:
        self.owner = owner
        key = space.heartbeat_of(principal)  # the router lets only `principal` publish it
        self._pub = session.declare_publisher(key, encoding=JSON, **STOP_QOS)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="liveness", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            seq = 0
            next_beat = time.monotonic()
            while not self._stop.is_set():
                beat = m.Heartbeat(time.time_ns(), self.owner, seq, HEARTBEAT_PERIOD_S)
                self._pub.put(encode(beat))
                seq += 1
                next_beat += HEARTBEAT_PERIOD_S
                self._stop.wait(max(0.0, next_beat - time.monotonic()))
        except BaseException:
            log.exception("liveness thread failed: agents will hold the arms")
            raise

    def close(self) -> None:
        """Stop beating (agents then hold arms still moving under this owner); idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._pub.undeclare()

    def __enter__(self) -> Liveness:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def settle(
    watch: ArmWatch,
    arms: Sequence[str],
    goal: Mapping[str, tuple[float, ...]] | None,
    timeout_s: float,
) -> dict[str, tuple[float, ...]]:
    """Wait (bounded) until every arm is still over 4 reports (and within 0.8 deg of ``goal``);
    returns each arm's last pose."""
    deadline = time.monotonic() + timeout_s
    history: dict[str, deque[tuple[float, ...]]] = {a: deque(maxlen=4) for a in arms}
    seen: dict[str, int] = {}
    poses: dict[str, tuple[float, ...]] = {}
    while time.monotonic() < deadline:
        for arm in arms:
            joints = watch.latest(arm).joints
            if joints is not None and seen.get(arm) != joints.seq:
                seen[arm] = joints.seq
                history[arm].append(tuple(joints.angles_deg))
                poses[arm] = tuple(joints.angles_deg)
        if all(
            len(h) == h.maxlen
            and _spread(h[0], h[-1]) < 0.3
            and (goal is None or _spread(h[-1], goal[a]) < 0.8)
            for a, h in history.items()
        ):
            break
        time.sleep(0.05)
    return poses


def _spread(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return max(abs(x - y) for x, y in zip(a, b))
