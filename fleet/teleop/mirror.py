"""``fleet mirror``: followers copy a leader arm that a person moves by hand (Unitree's D1-T).

The leader is unloaded (torque off: it can be dragged); its ``arm/<leader>/joints`` samples
reach our Zenoh callback, which only keeps the newest one and sets an Event. Our ``mirror``
thread (the caller's) sends each new sample, mapped per follower, as ``MoveJoints`` mode 0 to
every follower through a small pool (never waiting for a reply before the next sample).
Latency is measured per command: the leader sample's ``stamp_ns`` (its agent received it from
DDS) to the follower's DDS write (``CommandReply.written_ns``).

A stopped or lost leader (no sample for ``LEADER_LOST_S``), or a stopped or silent follower,
holds every follower and ends the mirror. A heartbeat with the mirror's id makes the agents
hold the followers if this process dies. Shutdown order: stop sending -> hold -> still ->
stop the heartbeat -> release the leases.
"""

from __future__ import annotations

import logging
import os
import socket
import statistics
import threading
import time
import uuid
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field

from fleet.client import FleetClient
from fleet.heartbeat import Liveness
from fleet.teleop.mapping import FollowerMap, MappingError
from fleet.watch import ArmWatch, settle
from fleet.wire import messages as m

log = logging.getLogger("fleet.mirror")

LEADER_LOST_S = 0.5
"""No leader sample for this long (five control cycles) means the leader is lost."""
TARGET_LIFETIME_S = 0.3


@dataclass
class MirrorResult:
    """How a mirror session ended, with the leader-sample -> follower-DDS-write latencies."""

    ok: bool = True
    reason: str = "stopped by the operator"
    samples: int = 0
    latencies_ms: list[float] = field(default_factory=list)

    def summary(self) -> str:
        """One line for the operator."""
        lat = sorted(self.latencies_ms)
        if lat:
            p95 = lat[min(len(lat) - 1, int(0.95 * len(lat)))]
            text = (
                f"latency leader sample -> follower DDS write: median "
                f"{statistics.median(lat):.1f} ms, p95 {p95:.1f} ms, max {lat[-1]:.1f} ms "
                f"({len(lat)} commands)"
            )
        else:
            text = "no command was sent"
        head = "mirror ended" if self.ok else "MIRROR HELD THE FOLLOWERS"
        return f"{head}: {self.reason}; {self.samples} leader samples; {text}"


class Mirror:
    """Mirrors ``leader`` onto the followers of ``mappings``."""

    def __init__(
        self,
        client: FleetClient,
        leader: str,
        mappings: list[FollowerMap],
        unload_leader: bool = True,
    ) -> None:
        if leader in {f.arm for f in mappings}:
            # The leader is unloaded to be moved by hand: as its own follower it would be
            # left unloaded and commanded at once.
            raise MappingError(f"arm {leader!r} cannot follow itself: pick another follower")
        self.client = client
        self.leader = leader
        self.mappings = mappings
        self.followers = [f.arm for f in mappings]
        self.unload_leader = unload_leader
        self.owner = f"mirror@{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"
        self.result = MirrorResult()
        self._newest: m.Joints | None = None
        self._lock = threading.Lock()  # guards _newest and result.latencies_ms
        self._fresh = threading.Event()
        self._pool = ThreadPoolExecutor(max_workers=2 * len(mappings) + 1, thread_name_prefix="cmd")

    def _on_joints(self, arm: str, joints: m.Joints) -> None:
        """Zenoh thread: keep the newest leader sample (latest wins), wake the mirror thread."""
        if arm == self.leader:
            with self._lock:
                self._newest = joints
            self._fresh.set()

    def run(self, stop: threading.Event, for_s: float | None = None) -> MirrorResult:
        """Mirror until ``stop``, ``for_s`` elapsed, or a problem (then the followers hold)."""
        watch = ArmWatch(
            self.client.session, self.client.keys, [self.leader, *self.followers], self._on_joints
        )
        client = self.client
        liveness = Liveness(
            client.session, client.keys, self.owner, client.principal, client.datagram
        )
        deadline = None if for_s is None else time.monotonic() + for_s
        try:
            stop.wait(0.3)  # the agents hear a beat first: followers are watched from move one
            self._start(watch)
            self._loop(watch, stop, deadline)
        except _Held as exc:
            self.result.ok, self.result.reason = False, str(exc)
            log.warning("mirror holds the followers: %s", exc)
            self._hold(watch)
        finally:
            settle(watch, self.followers, None, 1.0)
            liveness.close()
            self._broadcast(lambda a: m.Release(owner=self.owner))
            self._pool.shutdown(wait=False, cancel_futures=True)
            watch.close()
        return self.result

    def _start(self, watch: ArmWatch) -> None:
        problem = watch.wait_ready(3.0)
        if problem is not None:
            raise _Held(f"not started: {problem}")
        if self.unload_leader:
            reply = self.client.command(self.leader, m.Torque(on=False, owner=self.owner))
            if not reply.ok:
                raise _Held(f"could not unload leader {self.leader!r}: {reply.error}")
        with self._lock:
            leader = self._newest
        assert leader is not None
        # Catch up slowly (mode 1, waited) before streaming: no follower jumps to the leader.
        replies = self._broadcast(
            lambda a: m.MoveJoints(
                angles_deg=self._map(a).apply(leader.angles_deg),
                mode=1,
                owner=self.owner,
                wait_reached=True,
                tolerance_deg=3.0,
            )
        )
        failed = [r for r in replies.values() if not r.ok]
        if failed:
            raise _Held(f"follower {failed[0].arm!r} could not reach the leader: {failed[0].error}")

    def _loop(self, watch: ArmWatch, stop: threading.Event, deadline: float | None) -> None:
        with self._lock:  # the sample the followers caught up to is stale now: wait for a new one
            last_seq = self._newest.seq if self._newest is not None else -1
        self._fresh.clear()
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            self._fresh.wait(0.1)
            self._fresh.clear()
            now = time.monotonic()
            for arm in [self.leader, *self.followers]:
                problem = watch.problem(arm, now)
                if problem is not None:
                    raise _Held(problem)
            with self._lock:
                sample = self._newest
            leader_age = now - watch.latest(self.leader).joints_at
            if sample is None or leader_age > LEADER_LOST_S:
                raise _Held(f"leader {self.leader!r} lost: no joints for {leader_age:.2f} s")
            if sample.seq == last_seq:
                continue
            last_seq = sample.seq
            self.result.samples += 1
            for mapping in self.mappings:
                command = m.MoveJoints(
                    angles_deg=mapping.apply(sample.angles_deg),
                    mode=0,
                    owner=self.owner,
                    stamp_ns=time.time_ns(),
                    lifetime_s=TARGET_LIFETIME_S,
                )
                future = self._pool.submit(self.client.command, mapping.arm, command)
                future.add_done_callback(self._latency(sample.stamp_ns))

    def _latency(self, sample_ns: int):  # type: ignore[no-untyped-def]
        def done(future: Future[m.CommandReply]) -> None:
            if future.cancelled():
                return
            reply = future.result()
            if reply.ok and reply.written_ns is not None:
                with self._lock:
                    self.result.latencies_ms.append(round((reply.written_ns - sample_ns) / 1e6, 3))

        return done

    def _map(self, arm: str) -> FollowerMap:
        return next(f for f in self.mappings if f.arm == arm)

    def _broadcast(self, make) -> dict[str, m.CommandReply]:  # type: ignore[no-untyped-def]
        futures = {a: self._pool.submit(self.client.command, a, make(a)) for a in self.followers}
        wait(futures.values(), timeout=15.0)
        return {a: f.result() for a, f in futures.items() if f.done()}

    def _hold(self, watch: ArmWatch) -> None:
        """Hold every follower; once still, make that pose the watched target (see Player)."""
        self._broadcast(lambda a: m.Hold(owner=self.owner))
        still = settle(watch, self.followers, None, 1.5)
        self._broadcast(
            lambda a: (
                m.MoveJoints(angles_deg=list(still[a]), mode=0, owner=self.owner)
                if a in still
                else m.Hold(owner=self.owner)
            )
        )


class _Held(Exception):
    """The followers must be held; the message says why."""
