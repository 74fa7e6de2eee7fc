"""The choreography player: streams a timeline's targets to the arms at their control rate.

One thread of ours (the caller's) ticks at 10 Hz: it checks every arm (stopped, link, path
tolerance, failed replies), advances the pure ``Timeline`` and hands one ``MoveJoints`` (mode 0,
owner = the player, short lifetime) per D1 arm, and one ``arm_target`` per G1 whose arms the
script names (``g1_stream.py``), to a small thread pool: it never waits for a reply before the
next tick. ``Liveness`` beats with the player's id so the agents hold the D1 arms and release
the G1 arms if the player dies (their watchdog). Ticks that come late skip, and the timeline
holds through the stall (``timeline.PlayClock``); the play's state goes to
``choreo/<principal>`` (``announce.py``: the viewer shows a dance that stopped, and why).
Shutdown order: stop commanding -> hold every D1 arm -> wait until still -> give the G1 arms
back (weight 1 -> 0: a completed play only; an aborted one leaves them held, a stop never moves
them) and release their lease -> stop the heartbeat -> release the D1 leases -> undeclare.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field

from fleet.choreo.announce import PlayAnnouncer
from fleet.choreo.g1_arms import is_g1_arm
from fleet.choreo.g1_stream import G1Stream
from fleet.choreo.grip import GripDetector
from fleet.choreo.script import Pose, Script, ScriptError
from fleet.choreo.timeline import ArmFacts, Frame, PlayClock, Timeline, max_error_deg, next_tick
from fleet.choreo.validate import check_motion
from fleet.client import FleetClient, start_at_ns
from fleet.d1.limits import CONTROL_RATE_HZ, GRIPPER_JOINT, JointRanges
from fleet.devices.base import DeviceReply
from fleet.heartbeat import Liveness
from fleet.watch import ArmWatch, settle
from fleet.wire import messages as m

log = logging.getLogger("fleet.choreo")

ENDING_S = 5.0
"""The ending (hold, release the leases, give the G1 arms back) waits for the agents this long
in all, plus the G1 arms' weight ramp. The agents' own watchdogs hold the robots of a player
that goes silent, so a player whose fleet is gone (its demo killed) must not wait 5 s per step:
it took 8-30 s to exit."""
TARGET_LIFETIME_S = 0.3
"""A streamed target older than this is refused by the agent: three control cycles."""
PATH_WINDOW = 6
"""The measured pose is compared with the targets of the last 6 ticks (feedback lags ~0.1 s)."""
MAX_LATE_IN_A_ROW = 3
"""Streamed targets of one arm refused as late (past ``TARGET_LIFETIME_S``) in a row that
abort the play: one late target is skipped (the arm keeps the previous one and the next
supersedes it, 0.1 s later; seen at 320 ms on a loaded host), three mean the arm has had no
fresh target for a third of a second: the link or the host cannot carry the stream."""
MAX_PENDING = 3
"""Commands in flight per arm beyond which a tick skips the arm."""
KEYFRAME_WINDOW_S = 0.4
"""A keyframe's tracking error is the arm's closest approach within this time after the keyframe
(feedback is 10 Hz and ~0.1 s behind the command: the sample at the exact instant is stale)."""


@dataclass
class PlayResult:
    """How a play ended. ``keyframe_error_deg``: per finished keyframe, over the arms, the
    largest joint error of the closest sample within KEYFRAME_WINDOW_S after its time came;
    ``start_skew_ms``: spread of the first DDS writes (a G1's: when its agent took the first
    moving target; its 50 Hz stream writes it within 20 ms)."""

    ok: bool
    reason: str
    start_skew_ms: float | None = None
    keyframe_error_deg: list[float] = field(default_factory=list)
    max_path_error_deg: float = 0.0
    elapsed_s: float = 0.0
    overtaken: int = 0
    """Targets the agents refused as overtaken by a newer one of ours (the pool sent them out
    of order): harmless, the newer target was taken, but counted."""
    late: int = 0
    """Targets the agents refused as arrived past their lifetime, fewer than
    ``MAX_LATE_IN_A_ROW`` in a row for an arm (more abort the play): skipped, counted."""


class LateTargets:
    """Per unit (a D1 arm, ``g1 <id>``), its streamed targets refused as late since one of its
    targets was taken: fewer than ``limit`` in a row are skipped, ``limit`` abort."""

    def __init__(self, limit: int = MAX_LATE_IN_A_ROW) -> None:
        self.limit = limit
        self._in_a_row: dict[str, int] = {}

    def taken(self, unit: str) -> None:
        """A target of ``unit`` was taken."""
        self._in_a_row[unit] = 0

    def tolerable(self, unit: str) -> bool:
        """One more target of ``unit`` was refused as late: True while fewer than ``limit``
        in a row."""
        self._in_a_row[unit] = self._in_a_row.get(unit, 0) + 1
        return self._in_a_row[unit] < self.limit


def overtaken(error: m.ErrorInfo) -> bool:
    """The agent refused a streamed target because a newer one of ours got there first
    (``arm 'a2': out of order: ...``)."""
    return error.code == m.ErrorCode.OUT_OF_ORDER and f": {m.OVERTAKEN}: " in error.message


def path_error_deg(measured: Pose, target: Pose, closing_sign: float = -1.0) -> float:
    """How far an arm is off its path: the largest joint error, where a gripper that stopped
    more open than its target counts as on its path: it closed on an object, which is what a
    grip is (the agent's contact detector limits the squeeze). ``closing_sign``: which way
    ``angle6`` moves when the gripper closes (-1: towards 0, the default reading)."""
    arm = max_error_deg(measured[:GRIPPER_JOINT], target[:GRIPPER_JOINT])
    return max(arm, (measured[GRIPPER_JOINT] - target[GRIPPER_JOINT]) * closing_sign)


def player_id() -> str:
    """A unique owner id for one player."""
    return f"player@{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"


class Abort(Exception):
    """The play must stop now; the message says why."""


class Player:
    """Plays ``script`` on the arms it names, as owner ``owner``."""

    def __init__(
        self,
        client: FleetClient,
        script: Script,
        owner: str | None = None,
        on_progress: Callable[[Frame], None] | None = None,
    ) -> None:
        self.client = client
        self.script = script
        self.owner = owner or player_id()
        self.on_progress = on_progress
        self.period_s = 1.0 / CONTROL_RATE_HZ
        self.pool = ThreadPoolExecutor(
            max_workers=2 * len(script.arms) + 2, thread_name_prefix="cmd"
        )
        self.d1_arms = [a for a in script.arms if not is_g1_arm(a)]
        g1_arms = [a for a in script.arms if is_g1_arm(a)]
        self.g1 = (
            G1Stream(client, g1_arms, self.owner, self.pool, TARGET_LIFETIME_S) if g1_arms else None
        )
        self.pending: dict[str, deque[Future[m.CommandReply]]] = {a: deque() for a in self.d1_arms}
        self.recent: dict[str, deque[Pose]] = {a: deque(maxlen=PATH_WINDOW) for a in script.arms}
        arms = {a: client.inventory.arm(a) for a in self.d1_arms}
        self.ranges: dict[str, JointRanges] = {a: c.joint_ranges_deg for a, c in arms.items()}
        """Each arm's joint ranges: a D1's gripper reads its own way (inventory), a G1 arm's
        are its G1's."""
        self.caps: dict[str, float] = {}
        """Each G1 arm's top speed (deg/s), its G1's own."""
        if self.g1 is not None:
            self.ranges.update(self.g1.ranges())
            self.caps = self.g1.caps()
        self.closing = {a: c.gripper_closing_sign for a, c in arms.items()}
        self.grip = {a: GripDetector(closing_sign=self.closing[a]) for a in self.d1_arms}
        self._last_seq: dict[str, int] = {}
        self._late = LateTargets()
        # keyframes being measured: (deadline, goal per arm, best error per arm)
        self._keyframes: list[tuple[float, dict[str, Pose], dict[str, float]]] = []
        self.result = PlayResult(False, "not started")
        self._end_by: float | None = None
        """When the ending stops waiting for the agents (``ENDING_S``); None while playing."""

    # ------------------------------------------------------------------ public

    def play(self, stop: threading.Event | None = None, ready_s: float = 3.0) -> PlayResult:
        """Validate, start every arm at once, stream until done or aborted. Raises ScriptError
        (nothing moved) when the script breaks a joint or speed limit from the measured poses."""
        stop = stop or threading.Event()
        watch = ArmWatch(self.client.session, self.client.keys, self.d1_arms)
        client = self.client
        announce = PlayAnnouncer(
            client.session, client.keys, client.principal, self.owner, self.script.name
        )
        liveness: Liveness | None = None
        started = time.monotonic()
        try:
            poses = self.start_poses(watch, ready_s, stop)
            check_motion(self.script, poses, self.ranges, self.caps)
            client = self.client
            liveness = Liveness(
                client.session, client.keys, self.owner, client.principal, client.datagram
            )
            stop.wait(0.3)  # the agents hear a beat before the first move: the watchdog arms
            if self.g1 is not None:
                problem = self.g1.engage(stop)
                if problem is not None:
                    raise Abort(f"not started: {problem}")
            timeline = Timeline(self.script, poses)
            self._run(timeline, watch, stop, announce)
            self.result.ok, self.result.reason = True, "completed"
            announce.end(True, "completed")
        except ScriptError as exc:  # refused before anything moved
            self.result.reason = f"not started: {exc}"
            raise
        except Abort as exc:
            self.result.ok, self.result.reason = False, str(exc)
            announce.end(False, str(exc))  # before the ending: the viewer says so at once
            log.warning("choreography %r aborted: %s", self.script.name, exc)
            self._end_by = time.monotonic() + ENDING_S
            if liveness is not None:  # something may have moved: hold every D1 arm
                self._hold_all(watch)
        finally:
            if self._end_by is None:
                self._end_by = time.monotonic() + ENDING_S
            if liveness is not None and self.g1 is not None:
                # before the heartbeat stops: else the watchdog stops it. Aborted (a stop, a
                # problem): the G1 arms stay held where they are, as the D1 arms are.
                self.g1.release(self._left(), give_back_arms=self.result.ok)
            if liveness is not None:
                liveness.close()
                self._broadcast(lambda a: m.Release(owner=self.owner))
            self.pool.shutdown(wait=False, cancel_futures=True)
            watch.close()
            if self.g1 is not None:
                self.g1.close()
            self.result.elapsed_s = round(time.monotonic() - started, 3)
            announce.end(self.result.ok, self.result.reason)  # whatever ended it (idempotent)
            announce.close()
        return self.result

    def check(self, ready_s: float = 3.0) -> None:
        """Validate the script against the measured poses, moving nothing: ScriptError (a
        limit or speed problem), Abort (an arm is not ready)."""
        watch = ArmWatch(self.client.session, self.client.keys, self.d1_arms)
        try:
            check_motion(self.script, self.start_poses(watch, ready_s), self.ranges, self.caps)
        finally:
            watch.close()
            if self.g1 is not None:
                self.g1.close()
            self.pool.shutdown(wait=False)

    # ------------------------------------------------------------------ phases

    def start_poses(
        self, watch: ArmWatch, ready_s: float, stop: threading.Event | None = None
    ) -> dict[str, Pose]:
        """Every arm's measured pose once all are ready (bounded by ``ready_s``; ``stop``
        ends the wait); Abort."""
        problem = watch.wait_ready(ready_s, stop)
        if problem is not None:
            raise Abort(f"not started: {problem}")
        poses = {a: tuple(watch.latest(a).joints.angles_deg) for a in self.d1_arms}  # type: ignore[union-attr]
        if self.g1 is not None:
            g1_poses, problem = self.g1.start_poses(ready_s, stop)
            if problem is not None:
                raise Abort(f"not started: {problem}")
            poses.update(g1_poses)
        return poses

    def _measured(self, watch: ArmWatch, arm: str) -> Pose | None:
        """An arm's newest measured pose (deg), D1 or G1."""
        if self.g1 is not None and is_g1_arm(arm):
            return self.g1.measured(arm)
        joints = watch.latest(arm).joints
        return None if joints is None else tuple(joints.angles_deg)

    def _run(
        self,
        timeline: Timeline,
        watch: ArmWatch,
        stop: threading.Event,
        announce: PlayAnnouncer,
    ) -> None:
        start_ns = start_at_ns(self.script.start_lead_s)
        start_s = time.monotonic() + self.script.start_lead_s
        timeline.start(start_s)
        first = timeline.tick(start_s + self.period_s, {})
        self.result.start_skew_ms = self._synchronized_start(first, start_ns)
        tick = 1
        clock = PlayClock(self.period_s)
        shown = (-1, -1)
        last_shown_s = 0.0
        while True:
            due_s = start_s + tick * self.period_s
            stop.wait(max(0.0, due_s - time.monotonic()))
            if stop.is_set():
                raise Abort("interrupted by the operator")
            now = time.monotonic()
            self._check(watch, now)
            frame = timeline.tick(clock.play_time(due_s, now), self._facts(watch, timeline))
            self._book_keyframes(frame, watch, timeline)
            if frame.kind == "failed":
                raise Abort(frame.error or "a wait failed")
            if frame.kind == "done":
                settle(watch, self.d1_arms, timeline.poses, 3.0)
                if self.g1 is not None:
                    self.g1.settle(timeline.poses, self.script.reach_tolerance_deg, 3.0)
                self._book_keyframes(frame, watch, timeline, flush=True)
                return
            self._send(frame)
            announce.playing(frame.iteration, frame.label)
            if self.on_progress and (
                (frame.iteration, frame.step_index) != shown or now - last_shown_s >= 1.0
            ):
                self.on_progress(frame)
                shown, last_shown_s = (frame.iteration, frame.step_index), now
            tick = next_tick(tick, now - start_s, self.period_s)

    def _synchronized_start(self, frame: Frame, start_ns: int) -> float | None:
        """Every D1 arm gets its first target with the same ``start_at_ns`` (its agent writes
        it then); every G1 its first moving target at that instant from here (the G1's agent
        streams at 50 Hz and has no start time); returns the skew of the writes."""
        futures = {
            arm: self.pool.submit(
                self.client.command,
                arm,
                m.MoveJoints(
                    angles_deg=list(frame.targets[arm]),
                    mode=0,
                    owner=self.owner,
                    start_at_ns=start_ns,
                ),
            )
            for arm in self.d1_arms
        }
        g1_futures = {}
        if self.g1 is not None:
            time.sleep(max(0.0, (start_ns - time.time_ns()) / 1e9))
            g1_futures = self.g1.submit(frame.targets, time.time_ns())
        replies = [f.result() for f in futures.values()]
        for arm, reply in zip(futures, replies, strict=True):
            if not reply.ok:
                error = reply.error
                raise Abort(f"arm {arm!r} refused the start: {error.message if error else '?'}")
        written = [r.written_ns for r in replies if r.written_ns is not None]
        for device, future in g1_futures.items():
            g1_reply = future.result()
            if not g1_reply.ok:
                error = g1_reply.error
                raise Abort(f"g1 {device!r} refused the start: {error.message if error else '?'}")
            if g1_reply.written_ns is not None:
                written.append(g1_reply.written_ns)
        return round((max(written) - min(written)) / 1e6, 3) if len(written) > 1 else None

    # ------------------------------------------------------------------ per tick

    def _check(self, watch: ArmWatch, now: float) -> None:
        """Abort on a stopped or silent arm, a refused command, or an arm off its path."""
        replies: list[m.CommandReply | DeviceReply] = []
        for arm in self.d1_arms:
            problem = watch.problem(arm, now)
            if problem is not None:
                raise Abort(problem)
            queue = self.pending[arm]
            while queue and queue[0].done():
                replies.append(queue.popleft().result())
        if self.g1 is not None:
            problem = self.g1.problem(now)
            if problem is not None:
                raise Abort(problem)
            replies += self.g1.done_replies()
        for reply in replies:
            unit = reply.arm if isinstance(reply, m.CommandReply) else f"g1 {reply.device}"
            if reply.ok or reply.error is None:
                self._late.taken(unit)
            elif overtaken(reply.error):
                self.result.overtaken += 1  # a newer target of ours was already taken
            elif reply.error.code == m.ErrorCode.EXPIRED and self._late.tolerable(unit):
                self.result.late += 1  # skipped: the next target supersedes it
            else:
                again = f"{MAX_LATE_IN_A_ROW} in a row, the last: " * (
                    reply.error.code == m.ErrorCode.EXPIRED
                )
                raise Abort(
                    f"{unit!r} refused a target: [{reply.error.code}] {again}{reply.error.message}"
                )
        for arm in self.script.arms:
            measured = self._measured(watch, arm)
            if measured is None or not self.recent[arm]:
                continue
            closing = self.closing.get(arm)
            error = min(
                max_error_deg(measured, t)
                if closing is None
                else path_error_deg(measured, t, closing)
                for t in self.recent[arm]
            )
            self.result.max_path_error_deg = max(self.result.max_path_error_deg, round(error, 2))
            if error > self.script.tolerance_deg:
                raise Abort(
                    f"arm {arm!r} left its path: {error:.1f} deg from its targets "
                    f"(tolerance {self.script.tolerance_deg:g} deg)"
                )

    def _facts(self, watch: ArmWatch, timeline: Timeline) -> dict[str, ArmFacts]:
        facts = {}
        if self.g1 is not None:  # a G1 arm has no gripper: never gripped
            facts = {a: ArmFacts(self.g1.measured(a)) for a in self.script.arms if is_g1_arm(a)}
        for arm in self.d1_arms:
            latest = watch.latest(arm)
            angles = tuple(latest.joints.angles_deg) if latest.joints is not None else None
            if latest.joints is not None and self._last_seq.get(arm) != latest.joints.seq:
                self._last_seq[arm] = latest.joints.seq
                self.grip[arm].add(latest.joints.angles_deg)
            if latest.contact is not None:  # the agent's contact detector spoke: trust it
                gripped = latest.contact
            else:  # no detector word yet: the gripper stalled short of its target
                gripped = self.grip[arm].gripped(timeline.poses[arm][GRIPPER_JOINT])
            facts[arm] = ArmFacts(angles, gripped)
        return facts

    def _book_keyframes(
        self, frame: Frame, watch: ArmWatch, timeline: Timeline, flush: bool = False
    ) -> None:
        """Measure each keyframe as its arms' closest approach within KEYFRAME_WINDOW_S."""
        now = time.monotonic()
        for _index in [] if flush else frame.finished_keyframes:
            goal = {a: timeline.poses[a] for a in self.script.arms}
            self._keyframes.append((now + KEYFRAME_WINDOW_S, goal, {}))
        for deadline, goal, best in list(self._keyframes):
            for arm in self.script.arms:
                measured = self._measured(watch, arm)
                if measured is not None:
                    error = max_error_deg(measured, goal[arm])
                    best[arm] = min(best.get(arm, error), error)
            if flush or now >= deadline:
                self._keyframes.remove((deadline, goal, best))
                if best:
                    self.result.keyframe_error_deg.append(round(max(best.values()), 2))

    def _send(self, frame: Frame) -> None:
        stamp = time.time_ns()
        for arm in self.script.arms:
            self.recent[arm].append(frame.targets[arm])
        if self.g1 is not None:
            self.g1.submit(frame.targets, stamp)
        for arm in self.d1_arms:
            target = frame.targets[arm]
            if len(self.pending[arm]) >= MAX_PENDING:
                continue  # the agent is behind: skip this tick, the next target supersedes it
            command = m.MoveJoints(
                angles_deg=list(target),
                mode=0,
                owner=self.owner,
                stamp_ns=stamp,
                lifetime_s=TARGET_LIFETIME_S,
            )
            self.pending[arm].append(self.pool.submit(self.client.command, arm, command))

    # ------------------------------------------------------------------ ending

    def _left(self, most_s: float = 5.0) -> float:
        """How long one step may wait: ``most_s``, within the ending's budget once it began."""
        if self._end_by is None:
            return most_s
        return max(0.0, min(most_s, self._end_by - time.monotonic()))

    def _broadcast(self, make: Callable[[str], m.ArmCommand]) -> dict[str, m.CommandReply]:
        futures = {a: self.pool.submit(self.client.command, a, make(a)) for a in self.d1_arms}
        wait(futures.values(), timeout=self._left())
        return {a: f.result() for a, f in futures.items() if f.done()}

    def _hold_all(self, watch: ArmWatch) -> None:
        """Hold every arm where it is, then, once still, make that pose the watched target (so
        the agents' watchdog does not trip when the heartbeat stops after a clean abort)."""
        self._broadcast(lambda a: m.Hold(owner=self.owner))
        still = settle(watch, self.d1_arms, None, self._left(1.5))
        self._broadcast(
            lambda a: (
                m.MoveJoints(angles_deg=list(still[a]), mode=0, owner=self.owner)
                if a in still
                else m.Hold(owner=self.owner)
            )
        )
        settle(watch, self.d1_arms, None, self._left(1.0))
