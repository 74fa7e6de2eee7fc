"""``fleet ros2``: the fleet as ROS 2 nodes on rmw_zenoh's wire, on the fleet's own session.

Per arm and device, under its namespace (``[ros2.namespaces]``, default ``/<fleet>/<id>``), a
node ``d1_fleet`` publishing ``joint_states`` (arms: the URDF's names, radians, stamped with
the sample's time; Dex1-1: its motor's q), ``robot_description`` (arms, transient local: an
advanced publisher with a cache of 1 and publisher detection, as rmw_zenoh declares it) and
``diagnostics`` (from status/state and diag), and serving ``estop`` (std_srvs/Trigger: that
unit's protective stop). A fleet node ``/<fleet>/d1_fleet`` publishes ``/tf`` (every arm's links
from our forward kinematics, frames ``<id>/<link>``, under ``world``), ``/tf_static`` (each
base in the world, transient local) and serves ``/<fleet>/estop`` (the whole fleet's stop).

Threads. Data is published on the Zenoh thread that delivers it: one subscriber per channel
kind, whose callback decodes the sample (``payloads``), packs prepared CDR (a template per
unit: only the stamp and the numbers change) and puts it on a DROP publisher, which never
waits for a slow ROS subscriber. That is what zenoh's own ``z_pong`` does, it costs tens of
microseconds per sample, and it saves the hand-off to a thread of ours that made up most of
the added latency on a loaded host (issue 27: 7.2 ms p50 at load 5-6 with a ``ros2`` thread
and numpy kinematics per sample). Nothing there blocks or waits for the network. The
``ros2-estop`` thread puts each Trigger request's stop as it arrives, and a pool of
``ros2-stop`` workers answers them side by side (a stop waits for the agents' acks: it must not
stall joint states, nor the stops called after it). Bad samples are counted (``bad``); bad
requests (no or a malformed attachment, a payload that is no Trigger request, a flood) are
counted in ``bad_requests`` and refused or dropped; nothing dies of them. Shutdown: see
``Ros2Node.close``.
"""

from __future__ import annotations

import collections
import itertools
import logging
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Protocol

import zenoh
import zenoh.ext

from fleet.client import FleetClient
from fleet.devices import kind_of as device_kind
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.ros2 import contract as c
from fleet.ros2 import messages as msg
from fleet.ros2.devices import G1_JOINTS, gripper_joints
from fleet.ros2.diagnostics import arm_status, device_status
from fleet.security.session import open_session
from fleet.wire import keys, payloads
from fleet.wire.session import close_bounded

log = logging.getLogger("fleet.ros2")

NODE_NAME = "d1_fleet"
REQUEST_DEPTH = 64
"""Trigger requests waiting for the stop thread, and again requests waiting for their answer;
more are dropped and counted (a flood; a request dropped after its stop was put still
stopped)."""
STOP_WORKERS = 16
"""Trigger requests waiting for their acks at once; more wait for a worker to answer them
(their stops are put all the same, on arrival)."""
STOP_TIMEOUT_S = 3.0
TF_REFRESH_NS = 1_000_000_000
"""An arm at rest: its /tf once a second (tf2 keeps 10 s of history: RViz never loses it)."""
MISS_HEARTBEAT_MS = 500
"""rmw_zenoh's sporadic heartbeat of a reliable transient-local publisher."""


class ArmModels(Protocol):
    """What the node needs of the arms' kinematics (the CLI passes the URDF and its joints as
    ``fleet/ros2/frames.py`` frames: ``fleet`` never imports the viewer)."""

    joint_names: Sequence[str]

    def urdf(self, arm: str) -> str:
        """The arm's URDF (link names as in the file: RViz's RobotModel adds the TF prefix)."""

    def q(self, arm: str, angles_deg: Sequence[float]) -> list[float]:
        """Wire angles -> URDF joint values (radians; metres for the fingers)."""

    def static_transforms(self, arm: str) -> list[msg.Transform]:
        """World -> base, then parent -> child of every fixed joint, frames ``<arm>/<link>``."""

    def moving_frames(self, arm: str) -> list[tuple[str, str]]:
        """(parent, child) of every moving joint, frames ``<arm>/<link>``."""

    def moving_poses(self, arm: str, q: Sequence[float]) -> list[Any]:
        """x y z qx qy qz qw of every moving joint at ``q``, in ``moving_frames``' order."""


@dataclass
class _Publisher:
    key: str
    token_key: str
    gid: bytes
    publisher: Any
    token: Any = None
    # next() on a count is atomic: samples of one publisher may come from two Zenoh threads.
    sequence: Any = field(default_factory=lambda: itertools.count(1))

    def put(self, data: bytes, stamp_ns: int | None = None) -> None:
        stamp = time.time_ns() if stamp_ns is None else stamp_ns
        attachment = c.Attachment(next(self.sequence), stamp, self.gid).encode()
        self.publisher.put(data, attachment=attachment)


@dataclass
class _Unit:
    """One arm or device as a ROS node."""

    unit: str
    kind: str
    node: c.Node
    publishers: dict[str, _Publisher] = field(default_factory=dict)
    status: Any = None
    joint_states: msg.JointStateTemplate | None = None
    tf: msg.TfTemplate | None = None
    tf_angles: Any = None
    """The angles of the last /tf sent, and when (stamp_ns): /tf again on a change or after
    ``TF_REFRESH_NS``."""
    tf_stamp_ns: int = 0


class Ros2Node:
    """The fleet of ``inventory`` on rmw_zenoh's wire. A context manager."""

    def __init__(
        self, inventory: Inventory, arms: ArmModels, session: zenoh.Session | None = None
    ) -> None:
        self.inventory = inventory
        self.section = inventory.ros2
        self.models = arms
        self.keys = keys.KeySpace(inventory.fleet)
        self.domain = self.section.domain_id
        self.published = 0
        self.bad = 0
        self.bad_requests = 0
        self.stops = 0
        self.guard = ThreadGuard("ros2")
        self.failed = self.guard.failed
        self._requests: collections.deque[tuple[str | None, Any]] = collections.deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._closed = False
        self._own_session = session is None
        self.session = open_session(inventory) if session is None else session
        self.client = FleetClient(inventory, self.session)
        self.zid = str(self.session.info.zid())
        self._next_id = 0
        self._tokens: list[Any] = []
        self.units: dict[str, _Unit] = {}
        self._queryables: list[Any] = []
        try:
            self._declare()
            self._subscribers = self._subscribe()
        except BaseException:
            if self._own_session:
                self.session.close()
            raise
        self._workers = ThreadPoolExecutor(STOP_WORKERS, thread_name_prefix="ros2-stop")
        self._answering_lock = threading.Lock()
        self._answering = 0
        """Requests handed to the workers and not answered yet (at most REQUEST_DEPTH)."""
        self._threads = [self.guard.thread(self._serve_stops, "ros2-estop")]
        for thread in self._threads:
            thread.start()

    # ------------------------------------------------------------------ declarations

    def _id(self) -> int:
        self._next_id += 1
        return self._next_id

    def _node(self, namespace: str) -> c.Node:
        node = c.Node(self.domain, self.zid, self._id(), namespace, NODE_NAME)
        self._tokens.append(self.session.liveliness().declare_token(node.token()))
        return node

    def _publisher(
        self, node: c.Node, name: str, rtype: c.RosType, depth: int, latched: bool = False
    ) -> _Publisher:
        fqn = f"{node.namespace.rstrip('/')}/{name}" if not name.startswith("/") else name
        rtype = c.for_distro(rtype, self.section.distro)
        key = c.topic_key(self.domain, fqn, rtype)
        durability = c.TRANSIENT_LOCAL if latched else c.VOLATILE
        qos = c.qos_keyexpr(durability=durability, depth=depth)
        token_key = node.entity_token(self._id(), c.PUBLISHER, fqn, rtype, qos)
        if latched:
            publisher = zenoh.ext.declare_advanced_publisher(
                self.session,
                key,
                cache=zenoh.ext.CacheConfig(depth),
                publisher_detection=True,
                sample_miss_detection=zenoh.ext.MissDetectionConfig(
                    sporadic_heartbeat=MISS_HEARTBEAT_MS
                ),
            )
        else:
            # DROP, as rmw_zenoh's keep-last publishers: a slow ROS subscriber never stalls us.
            publisher = self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.DROP
            )
        out = _Publisher(key, token_key, c.gid_of(token_key), publisher)
        out.token = self.session.liveliness().declare_token(token_key)
        return out

    def _service(self, node: c.Node, fqn: str, unit: str | None) -> None:
        trigger = c.for_distro(c.TRIGGER, self.section.distro)
        key = c.topic_key(self.domain, fqn, trigger)
        qos = c.qos_keyexpr(depth=10)
        token = node.entity_token(self._id(), c.SERVICE, fqn, trigger, qos)
        self._tokens.append(self.session.liveliness().declare_token(token))

        def on_query(query: zenoh.Query) -> None:  # Zenoh thread: hand off, never block
            if len(self._requests) >= REQUEST_DEPTH:
                self.bad_requests += 1
                return
            self._requests.append((unit, query))
            self._wake.set()

        self._queryables.append(
            self.session.declare_queryable(key, self.guard.wrap(on_query), complete=True)
        )

    def _declare(self) -> None:
        fleet_ns = f"/{self.inventory.fleet.replace('-', '_')}"
        fleet_node = self._node(fleet_ns)
        self._tf = self._publisher(fleet_node, "/tf", c.TF_MESSAGE, 100)
        self._tf_static = self._publisher(fleet_node, "/tf_static", c.TF_MESSAGE, 1, latched=True)
        self._service(fleet_node, f"{fleet_ns}/estop", None)
        arm_joints = msg.JointStateTemplate(self.models.joint_names)
        for arm in self.inventory.arms:
            unit = _Unit(
                arm, keys.ARM, self._node(self.section.namespace(self.inventory.fleet, arm))
            )
            unit.publishers["joint_states"] = self._publisher(
                unit.node, "joint_states", c.JOINT_STATE, 10
            )
            unit.publishers["robot_description"] = self._publisher(
                unit.node, "robot_description", c.STRING, 1, latched=True
            )
            unit.joint_states = arm_joints
            unit.tf = msg.TfTemplate(
                [(self._name(p), self._name(ch)) for p, ch in self.models.moving_frames(arm)]
            )
            self.units[arm] = unit
        for device_id, device in self.inventory.devices.items():
            kind = device_kind(device).key
            ns = self.section.namespace(self.inventory.fleet, device_id)
            unit = _Unit(device_id, kind, self._node(ns))
            if kind == keys.GRIPPER:
                unit.joint_states = msg.JointStateTemplate(
                    gripper_joints(device_id), velocity=True, effort=True
                )
            elif kind == keys.G1:
                unit.joint_states = msg.JointStateTemplate(G1_JOINTS)
            if unit.joint_states is not None:
                unit.publishers["joint_states"] = self._publisher(
                    unit.node, "joint_states", c.JOINT_STATE, 10
                )
            self.units[device_id] = unit
        for unit in self.units.values():
            unit.publishers["diagnostics"] = self._publisher(
                unit.node, "diagnostics", c.DIAGNOSTIC_ARRAY, 10
            )
            self._service(unit.node, f"{unit.node.namespace}/estop", unit.unit)
        for arm in self.inventory.arms:
            self.units[arm].publishers["robot_description"].put(msg.string(self.models.urdf(arm)))
        # Each base in the world and every fixed joint: sent once, as robot_state_publisher
        # does (only the moving joints are /tf, per sample).
        static = [
            msg.Transform(self._name(t.parent), self._name(t.child), t.xyz, t.xyzw)
            for arm in self.inventory.arms
            for t in self.models.static_transforms(arm)
        ]
        self._tf_static.put(msg.tf_message(time.time_ns(), static))

    def _name(self, frame: str) -> str:
        """The inventory's world frame for ``world``; without ``frame_prefix``, bare links."""
        if frame == "world":
            return self.section.world_frame
        return frame if self.section.frame_prefix else frame.partition("/")[2]

    # ------------------------------------------------------------------ data

    def _subscribe(self) -> list[Any]:
        """One subscriber per channel kind this node publishes from."""
        handlers: list[tuple[str, str, Callable[[_Unit, Any], None]]] = [
            (self.keys.all_arms(keys.JOINTS), keys.JOINTS, self._joints),
            (self.keys.all_arms(keys.STATUS), keys.STATUS, self._state),
            (self.keys.all_arms(keys.DIAG), keys.DIAG, self._diag),
        ]
        for kind in sorted({u.kind for u in self.units.values() if u.kind != keys.ARM}):
            handlers.append((self.keys.device(kind, "*", keys.STATE), f"{kind}/state", self._state))
            handlers.append((self.keys.device(kind, "*", keys.DIAG), f"{kind}/diag", self._diag))
            if kind == keys.G1:
                low = self.keys.device(kind, "*", keys.LOWSTATE)
                handlers.append((low, f"{kind}/lowstate", self._lowstate))
        return [
            self.session.declare_subscriber(key, self.guard.wrap(self._on(kind, handle)))
            for key, kind, handle in handlers
        ]

    def _on(self, kind: str, handle: Callable[[_Unit, Any], None]) -> Callable[[Any], None]:
        """A Zenoh callback for the samples of ``kind``: decode, find the unit, publish (see the
        module's docstring for why here)."""
        unit_at = len(self.keys.prefix.split("/")) + 1  # fleet/<fleet>/<kind>/<unit>/...

        def on_sample(sample: zenoh.Sample) -> None:
            parts = str(sample.key_expr).split("/")
            unit = self.units.get(parts[unit_at]) if len(parts) > unit_at else None
            if unit is None or self._closed:
                return
            try:
                payload = payloads.decode(kind, sample.payload.to_bytes())
            except payloads.PayloadError:
                self.bad += 1
                return
            handle(unit, payload)

        return on_sample

    def _state(self, unit: _Unit, state: Any) -> None:
        """An arm's status or a device's state: kept for its diagnostics; a Dex1-1's motor is
        its joint state."""
        unit.status = state
        if unit.kind == keys.GRIPPER and unit.joint_states is not None:
            data = unit.joint_states.message(
                state.stamp_ns, [state.q_rad], [state.dq_rad_s], [state.tau_est]
            )
            unit.publishers["joint_states"].put(data, state.stamp_ns)
            self.published += 1

    def _lowstate(self, unit: _Unit, low: Any) -> None:
        """A G1's rt/lowstate: its 29 joints in Unitree's motor order."""
        if unit.joint_states is None or len(low.q_rad) != len(G1_JOINTS):
            self.bad += 1
            return
        unit.publishers["joint_states"].put(
            unit.joint_states.message(low.stamp_ns, low.q_rad), low.stamp_ns
        )
        self.published += 1

    def _diag(self, unit: _Unit, diag: Any) -> None:
        """Once a second: the unit's diagnostics."""
        make = arm_status if unit.kind == keys.ARM else device_status
        status = make(unit.unit, unit.kind, unit.status, diag, self.inventory.fleet)
        unit.publishers["diagnostics"].put(msg.diagnostic_array(time.time_ns(), [status]))
        self.published += 1

    def _joints(self, unit: _Unit, joints: Any) -> None:
        """An arm's joints: its joint_states, then its moving joints on /tf when they moved (or
        a second passed)."""
        if len(joints.angles_deg) != 7 or unit.joint_states is None or unit.tf is None:
            self.bad += 1
            return
        stamp = joints.stamp_ns
        q = self.models.q(unit.unit, joints.angles_deg)
        unit.publishers["joint_states"].put(unit.joint_states.message(stamp, q), stamp)
        self.published += 1
        if joints.angles_deg == unit.tf_angles and 0 <= stamp - unit.tf_stamp_ns < TF_REFRESH_NS:
            return
        unit.tf_angles, unit.tf_stamp_ns = joints.angles_deg, stamp
        self._tf.put(unit.tf.message(stamp, self.models.moving_poses(unit.unit, q)), stamp)
        self.published += 1

    # ------------------------------------------------------------------ stops

    def _serve_stops(self) -> None:
        """The ``ros2-estop`` thread: each request's stop is put at once, in arrival order;
        waiting for its acks and replying happen on the ``ros2-stop`` workers, side by side
        (one after another, ten calls to a unit whose agent is down held a fleet stop behind
        them for ten ack timeouts: 30 s)."""
        while not self._stop.is_set():
            if not self._requests:
                self._wake.wait(0.1)
                self._wake.clear()
                continue
            unit, query = self._requests.popleft()
            answer = self._start(unit, query)
            if answer is None:
                query.drop()
                continue
            with self._answering_lock:
                room = self._answering < REQUEST_DEPTH
                if room:
                    self._answering += 1
            if room:
                self._workers.submit(self.guard.wrap(self._answered(answer), "ros2-stop"))
            else:  # a flood: its stop was put all the same; its answer is dropped, counted
                self.bad_requests += 1
                query.drop()

    def _answered(self, answer: Callable[[], None]) -> Callable[[], None]:
        """``answer``, then one request fewer being answered."""

        def run() -> None:
            try:
                answer()
            finally:
                with self._answering_lock:
                    self._answering -= 1

        return run

    def _start(self, unit: str | None, query: zenoh.Query) -> Callable[[], None] | None:
        """Check a Trigger request and put its stop; what answers it (None: nothing to
        answer: no client GID or sequence number to address a reply to)."""
        attachment = query.attachment
        try:
            request = c.decode_attachment(None if attachment is None else attachment.to_bytes())
        except c.AttachmentError as exc:
            self.bad_requests += 1
            log.warning("ignored a Trigger request on %s: %s", query.key_expr, exc)
            return None
        payload = query.payload
        reply_to = c.Attachment(request.sequence, time.time_ns(), request.gid).encode()
        if payload is None or not msg.trigger_request_ok(payload.to_bytes()):
            self.bad_requests += 1
            refused = msg.trigger_response(False, "refused: not a std_srvs/srv/Trigger request")
            return lambda: self._reply(query, refused, reply_to)
        self.stops += 1
        source = f"ros2:{self.inventory.principal}"
        stop = self.client.stop_request(reason="ROS 2 Trigger", source=source)
        self.client.put_stop(stop, unit)  # acted on now, whatever the workers are waiting for

        def answer() -> None:
            response = msg.trigger_response(*self._stop_unit(unit, stop))
            self._reply(query, response, reply_to)

        return answer

    @staticmethod
    def _reply(query: zenoh.Query, response: bytes, reply_to: bytes) -> None:
        try:
            query.reply(query.key_expr, response, attachment=reply_to)
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    def _stop_unit(self, unit: str | None, stop: Any) -> tuple[bool, str]:
        """Wait for the agents' acks of ``stop``, already put (the whole fleet's, or one arm's
        or device's), repeating it as every client does."""
        acks = self.client.estop(unit, timeout_s=STOP_TIMEOUT_S, wait_still=False, request=stop)
        missing = sorted(name for name, ack in acks.items() if ack is None)
        done = sorted(name for name, ack in acks.items() if ack is not None)
        if missing:
            acked = ", ".join(done) or "none"
            return False, f"stop sent; acknowledged by {acked}; no ack from {', '.join(missing)}"
        return True, f"stopped {', '.join(done)}"

    # ------------------------------------------------------------------ shutdown

    def close(self) -> None:
        """Undeclare queryables and subscribers -> stop the thread -> let the workers answer
        the stops they wait for (each within STOP_TIMEOUT_S; those not started are dropped)
        -> undeclare tokens and publishers -> close the session if ours (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for queryable in self._queryables:
            queryable.undeclare()
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self._stop.set()
        self._wake.set()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=STOP_TIMEOUT_S + 2.0)
        self._workers.shutdown(wait=True, cancel_futures=True)
        publishers = [self._tf, self._tf_static]
        publishers += [p for u in self.units.values() for p in u.publishers.values()]
        for p in publishers:
            p.token.undeclare()
            p.publisher.undeclare()
        for token in self._tokens:
            token.undeclare()
        if self._own_session:
            close_bounded(self.session, "session")

    def __enter__(self) -> Ros2Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
