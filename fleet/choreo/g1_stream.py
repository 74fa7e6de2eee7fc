"""The choreography player's hand on the G1s whose arms a script names: one ``arm_target`` per
G1 per tick (both arms and the waist, ``fleet/choreo/g1_arms.py``), through the agent that
serves it and its own checks (seed 004's FSM states, joint limits, the distance from the
measured pose), its lease and its watchdog.

A G1's arms are engaged before the synchronized start: the first target is the pose measured
now, which the agent holds at weight 1 (or ramps the rt/arm_sdk weight 0 -> 1 over the G1's
``arm_engage_s`` when it knows the robot's weight is 0), so the robot does not move until the
start. They are released at the end of a completed play: ``arm_release`` ramps the weight
1 -> 0 over ``arm_release_s``. An aborted play (a stop among them) leaves them held where they
are, as it holds the D1 arms, and so does the agent on a stop, its lease or the watchdog when
the player dies (``arm_on_stop``), until someone releases them.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait

from fleet.choreo import g1_arms
from fleet.choreo.g1_arms import Pose
from fleet.choreo.g1_watch import G1Watch
from fleet.choreo.timeline import max_error_deg
from fleet.client import FleetClient
from fleet.d1.limits import JointRanges
from fleet.devices.base import DeviceReply
from fleet.g1.config import G1Config, arm_limits
from fleet.g1.messages import ArmRelease, ArmTarget
from fleet.wire.messages import DeviceRelease

MAX_PENDING = 3
"""Targets in flight per G1 beyond which a tick skips it (the next target supersedes)."""
ENGAGE_MARGIN_S = 2.0
"""Engaging may take this much longer than the G1's ``arm_engage_s`` (its agent's 50 Hz
stream, the state's relay rate)."""
RELEASED_MARGIN_S = 1.0
"""Waiting for the weight's return to 0 may take this much longer than ``arm_release_s``."""


class G1Stream:
    """Streams a script's G1 arm targets (``arms``: its G1 arm names) as ``owner``."""

    def __init__(
        self,
        client: FleetClient,
        arms: Sequence[str],
        owner: str,
        pool: ThreadPoolExecutor,
        lifetime_s: float,
    ) -> None:
        self.client = client
        self.sides = g1_arms.devices_of(arms)
        self.configs: dict[str, G1Config] = {}
        for device in self.sides:
            config = client.inventory.device(device)
            if not isinstance(config, G1Config):  # the script's parser checked it
                raise ValueError(f"{device!r} is not a G1 of the inventory")
            self.configs[device] = config
        self.owner = owner
        self.pool = pool
        self.lifetime_s = lifetime_s
        self.watch = G1Watch(client.session, client.keys, self.sides)
        self.held: dict[str, list[float]] = {}
        """Each G1's 17 rt/arm_sdk joints (rad) measured at the start: the waist and any arm
        the script does not name keep them."""
        self.pending: dict[str, deque[Future[DeviceReply]]] = {d: deque() for d in self.sides}
        self.engaged = False

    # ------------------------------------------------------------------ limits and poses

    def ranges(self) -> dict[str, JointRanges]:
        """Each G1 arm's joint ranges (deg), from its G1's limits."""
        return {
            g1_arms.arm_name(d, side): g1_arms.joint_ranges_deg(side, arm_limits(self.configs[d]))
            for d, sides in self.sides.items()
            for side in sides
        }

    def caps(self) -> dict[str, float]:
        """Each G1 arm's top joint speed (deg/s): its G1's ``arm_max_speed_rad_s``."""
        return {
            g1_arms.arm_name(d, side): g1_arms.max_speed_deg_s(self.configs[d])
            for d, sides in self.sides.items()
            for side in sides
        }

    def measured(self, arm: str) -> Pose | None:
        """A G1 arm's newest measured pose (deg), None without a lowstate."""
        parts = g1_arms.split(arm)
        assert parts is not None
        low = self.watch.latest(parts[0]).low
        return None if low is None else g1_arms.side_pose_deg(low.q_rad, parts[1])

    def start_poses(
        self, ready_s: float, stop: threading.Event | None = None
    ) -> tuple[dict[str, Pose], str | None]:
        """Wait (bounded; ``stop`` ends it) until every G1 may be commanded; each arm's pose
        (deg) and the problem left, if any. Remembers the held pose of each G1."""
        problem = self.watch.wait_ready(ready_s, stop)
        if problem is not None:
            return {}, problem
        poses: dict[str, Pose] = {}
        for device, sides in self.sides.items():
            low = self.watch.latest(device).low
            assert low is not None  # wait_ready saw it
            self.held[device] = g1_arms.waist_and_arms_rad(low.q_rad)
            for side in sides:
                poses[g1_arms.arm_name(device, side)] = g1_arms.side_pose_deg(low.q_rad, side)
        return poses, None

    def problem(self, now_s: float) -> str | None:
        """Why a G1 must not be commanded any more (stopped, silent, released), or None."""
        for device in self.sides:
            why = self.watch.problem(device, now_s)
            if why is None and self.engaged:
                why = self.watch.released(device)
            if why is not None:
                return why
        return None

    # ------------------------------------------------------------------ commanding

    def _target(self, device: str, targets: Mapping[str, Pose], stamp_ns: int) -> ArmTarget:
        sides = {s: targets[g1_arms.arm_name(device, s)] for s in self.sides[device]}
        return ArmTarget(
            q_rad=g1_arms.target_rad(self.held[device], sides),
            # the timeline limits the speed (validated against this cap): the agent's stream
            # only has to keep up with it.
            speed_rad_s=self.configs[device].arm_max_speed_rad_s,
            owner=self.owner,
            stamp_ns=stamp_ns,
            lifetime_s=self.lifetime_s,
        )

    def engage(self, stop: threading.Event) -> str | None:
        """Hold every G1's measured pose with the weight ramped to 1; the problem, or None."""
        stamp = time.time_ns()
        futures = {
            d: self.pool.submit(self.client.device_command, d, self._held_target(d, stamp))
            for d in self.sides
        }
        for device, future in futures.items():
            reply = future.result()
            if not reply.ok:
                return f"g1 {device!r} refused its arms' first target: {_why(reply)}"
        longest = max(c.arm_engage_s for c in self.configs.values()) + ENGAGE_MARGIN_S
        deadline = time.monotonic() + longest
        while not stop.is_set():
            states = [self.watch.latest(d).state for d in self.sides]
            if all(s is not None and s.arm_phase == "on" for s in states):
                self.engaged = True  # from now on, a released stream is a problem
                return None
            problem = self.problem(time.monotonic())  # (the state may still say "off")
            if problem is not None:
                return problem
            if time.monotonic() >= deadline:
                return f"the G1 arms' weight did not reach 1 within {longest:g} s"
            stop.wait(0.05)
        return "interrupted by the operator"

    def _held_target(self, device: str, stamp_ns: int) -> ArmTarget:
        return ArmTarget(
            q_rad=list(self.held[device]),
            owner=self.owner,
            stamp_ns=stamp_ns,
            lifetime_s=self.lifetime_s,
        )

    def submit(self, targets: Mapping[str, Pose], stamp_ns: int) -> dict[str, Future[DeviceReply]]:
        """One target per G1 (skipped while MAX_PENDING are in flight); their futures."""
        sent = {}
        for device in self.sides:
            if len(self.pending[device]) >= MAX_PENDING:
                continue  # the agent is behind: the next target supersedes this one
            command = self._target(device, targets, stamp_ns)
            future = self.pool.submit(self.client.device_command, device, command)
            self.pending[device].append(future)
            sent[device] = future
        return sent

    def done_replies(self) -> list[DeviceReply]:
        """The replies of the targets answered since the last call, oldest first."""
        replies = []
        for queue in self.pending.values():
            while queue and queue[0].done():
                replies.append(queue.popleft().result())
        return replies

    def settle(self, goal: Mapping[str, Pose], tolerance_deg: float, timeout_s: float) -> None:
        """Wait (bounded) until every G1 arm is within ``tolerance_deg`` of ``goal``."""
        deadline = time.monotonic() + timeout_s
        arms = [g1_arms.arm_name(d, s) for d, sides in self.sides.items() for s in sides]
        while time.monotonic() < deadline:
            poses = {a: self.measured(a) for a in arms}
            if all(
                p is not None and max_error_deg(p, goal[a]) <= tolerance_deg
                for a, p in poses.items()
            ):
                return
            time.sleep(0.05)

    def release(self, answers_s: float = 5.0, give_back_arms: bool = True) -> None:
        """End the lease; with ``give_back_arms`` first give the arms back to the robots (weight
        1 -> 0) and wait (bounded) for the weight's return to 0. Without, the agent keeps them
        where they are (held, the weight kept) until an ``arm_release``. The agents' answers are
        awaited ``answers_s`` in all."""
        answer_by = time.monotonic() + answers_s
        makes = [lambda: DeviceRelease(owner=self.owner)]
        if give_back_arms:
            makes.insert(0, lambda: ArmRelease(owner=self.owner))
        for make in makes:
            futures = [self.pool.submit(self.client.device_command, d, make()) for d in self.sides]
            wait(futures, timeout=max(0.0, answer_by - time.monotonic()))
        if not give_back_arms:
            return
        longest = max(c.arm_release_s for c in self.configs.values()) + RELEASED_MARGIN_S
        deadline = time.monotonic() + longest
        while time.monotonic() < deadline:
            states = [self.watch.latest(d).state for d in self.sides]
            if all(s is None or s.arm_phase == "off" for s in states):
                return
            time.sleep(0.05)

    def close(self) -> None:
        """Undeclare the watch (idempotent)."""
        self.watch.close()


def _why(reply: DeviceReply) -> str:
    error = reply.error
    return f"[{error.code}] {error.message}" if error is not None else "no reason given"
