"""``fleet ros2``: the fleet as ROS 2 nodes on rmw_zenoh's wire, on the fleet's own session.

Per arm and device, under its namespace (``[ros2.namespaces]``, default ``/<fleet>/<id>``), a
node ``d1_fleet`` publishing ``joint_states`` (arms: the URDF's names, radians, stamped with
the sample's time; Dex1-1: its motor's q), ``robot_description`` (arms, transient local: an
advanced publisher with a cache of 1 and publisher detection, as rmw_zenoh declares it) and
``diagnostics`` (from status/state and diag), and serving ``estop`` (std_srvs/Trigger: that
unit's protective stop). A fleet node ``/<fleet>/d1_fleet`` publishes ``/tf`` (every arm's links
from our forward kinematics, frames ``<id>/<link>``, under ``world``), ``/tf_static`` (each
base in the world, transient local) and serves ``/<fleet>/estop`` (the whole fleet's stop).

Threads: Zenoh callbacks only append to bounded deques (overflow counted); the ``ros2`` thread
decodes (the channel table) and publishes; the ``ros2-estop`` thread answers Trigger requests
(a stop waits for the agents' acks: it must not stall joint states). Bad requests (no or a
malformed attachment, a payload that is no Trigger request, a flood) are counted in
``bad_requests`` and refused or dropped; the thread never dies of them. Shutdown: undeclare the
queryables and subscribers -> stop the threads -> undeclare tokens and publishers -> close the
session (if ours).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Sequence
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
from fleet.ros2.diagnostics import arm_status, device_status
from fleet.security.session import open_session
from fleet.tap import kind_of
from fleet.wire import keys, payloads

log = logging.getLogger("fleet.ros2")

NODE_NAME = "d1_fleet"
INBOX_DEPTH = 10_000
REQUEST_DEPTH = 64
"""Trigger requests waiting for the stop thread; more are dropped and counted (a flood)."""
STOP_TIMEOUT_S = 3.0
MISS_HEARTBEAT_MS = 500
"""rmw_zenoh's sporadic heartbeat of a reliable transient-local publisher."""


class ArmModels(Protocol):
    """What the node needs of the arms' kinematics (the CLI passes the URDF and forward
    kinematics of ``fleet/scene3d``, which needs numpy and yourdfpy: the node itself does not)."""

    joint_names: Sequence[str]

    def urdf(self, arm: str) -> str:
        """The arm's URDF (link names as in the file: RViz's RobotModel adds the TF prefix)."""

    def q(self, arm: str, angles_deg: Sequence[float]) -> list[float]:
        """Wire angles -> URDF joint values (radians; metres for the fingers)."""

    def transforms(self, arm: str, angles_deg: Sequence[float]) -> list[msg.Transform]:
        """World -> base, then parent -> child of every link, frames ``<arm>/<link>``."""


@dataclass
class _Publisher:
    key: str
    token_key: str
    gid: bytes
    publisher: Any
    token: Any = None
    sequence: int = 0

    def put(self, data: bytes, stamp_ns: int | None = None) -> None:
        self.sequence += 1
        stamp = time.time_ns() if stamp_ns is None else stamp_ns
        attachment = c.Attachment(self.sequence, stamp, self.gid).encode()
        self.publisher.put(data, attachment=attachment)


@dataclass
class _Unit:
    """One arm or device as a ROS node."""

    unit: str
    kind: str
    node: c.Node
    publishers: dict[str, _Publisher] = field(default_factory=dict)
    status: Any = None


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
        self.dropped = 0
        self.bad = 0
        self.bad_requests = 0
        self.stops = 0
        self.guard = ThreadGuard("ros2")
        self.failed = self.guard.failed
        self._inbox: collections.deque[tuple[str, bytes]] = collections.deque()
        self._requests: collections.deque[tuple[str | None, Any]] = collections.deque()
        self._wake = threading.Event()
        self._data = threading.Event()
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
            self._subscriber = self.session.declare_subscriber(
                self.keys.everything, self._on_sample
            )
        except BaseException:
            if self._own_session:
                self.session.close()
            raise
        self._threads = [
            self.guard.thread(self._run, "ros2"),
            self.guard.thread(self._serve_stops, "ros2-estop"),
        ]
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
        key = c.topic_key(self.domain, fqn, c.TRIGGER)
        qos = c.qos_keyexpr(depth=10)
        token = node.entity_token(self._id(), c.SERVICE, fqn, c.TRIGGER, qos)
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
            self.units[arm] = unit
        for device_id, device in self.inventory.devices.items():
            kind = device_kind(device).key
            ns = self.section.namespace(self.inventory.fleet, device_id)
            unit = _Unit(device_id, kind, self._node(ns))
            if kind == keys.GRIPPER:
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
        bases = [
            self._frame(t)
            for arm in self.inventory.arms
            for t in self.models.transforms(arm, [0.0] * 7)[:1]
        ]
        self._tf_static.put(msg.tf_message(time.time_ns(), bases))

    def _frame(self, t: msg.Transform) -> msg.Transform:
        """``t`` with the inventory's world frame and, without ``frame_prefix``, bare links."""

        def name(frame: str) -> str:
            if frame == "world":
                return self.section.world_frame
            return frame if self.section.frame_prefix else frame.partition("/")[2]

        return msg.Transform(name(t.parent), name(t.child), t.xyz, t.xyzw)

    # ------------------------------------------------------------------ data

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: hand off, never block."""
        if len(self._inbox) < INBOX_DEPTH:
            self._inbox.append((str(sample.key_expr), sample.payload.to_bytes()))
            self._data.set()
        else:
            self.dropped += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self._inbox:
                # Woken by the callback (no polling: latency and idle CPU), or by close().
                self._data.wait(0.1)
                self._data.clear()
                continue
            for _ in range(min(len(self._inbox), 256)):
                self._publish(*self._inbox.popleft())

    def _publish(self, key: str, data: bytes) -> None:
        kind = kind_of(self.keys, key)
        if kind not in (keys.JOINTS, keys.STATUS, keys.DIAG, "gripper/state", "g1/state") and not (
            kind is not None and kind.endswith("/diag")
        ):
            return
        try:
            parsed = self.keys.parse_key(key)
            payload = payloads.decode(kind, data)
        except (keys.KeyError_, payloads.PayloadError):
            self.bad += 1
            return
        unit = self.units.get(parsed.unit)
        if unit is None:
            return
        if kind == keys.JOINTS:
            self._joints(unit, payload)
        elif kind in (keys.STATUS, "gripper/state", "g1/state"):
            unit.status = payload
            if kind == "gripper/state" and payload.q_rad is not None:
                stamp = payload.stamp_ns
                data = msg.joint_state(stamp, [f"{unit.unit}_joint"], [payload.q_rad])
                unit.publishers["joint_states"].put(data, stamp)
                self.published += 1
        else:  # diag, once a second: the diagnostics of the unit
            make = arm_status if unit.kind == keys.ARM else device_status
            status = make(unit.unit, unit.kind, unit.status, payload, self.inventory.fleet)
            unit.publishers["diagnostics"].put(msg.diagnostic_array(time.time_ns(), [status]))
            self.published += 1

    def _joints(self, unit: _Unit, joints: Any) -> None:
        if len(joints.angles_deg) != 7:
            self.bad += 1
            return
        stamp = joints.stamp_ns
        q = self.models.q(unit.unit, joints.angles_deg)
        data = msg.joint_state(stamp, self.models.joint_names, q)
        unit.publishers["joint_states"].put(data, stamp)
        links = [self._frame(t) for t in self.models.transforms(unit.unit, joints.angles_deg)[1:]]
        self._tf.put(msg.tf_message(stamp, links), stamp)
        self.published += 2

    # ------------------------------------------------------------------ stops

    def _serve_stops(self) -> None:
        while not self._stop.is_set():
            if not self._requests:
                self._wake.wait(0.1)
                self._wake.clear()
                continue
            unit, query = self._requests.popleft()
            try:
                self._answer(unit, query)
            finally:
                query.drop()

    def _answer(self, unit: str | None, query: zenoh.Query) -> None:
        attachment = query.attachment
        try:
            request = c.decode_attachment(None if attachment is None else attachment.to_bytes())
        except c.AttachmentError as exc:
            # No client GID or sequence number: nothing to address a reply to.
            self.bad_requests += 1
            log.warning("ignored a Trigger request on %s: %s", query.key_expr, exc)
            return
        payload = query.payload
        reply_to = c.Attachment(request.sequence, time.time_ns(), request.gid).encode()
        if payload is None or not msg.trigger_request_ok(payload.to_bytes()):
            self.bad_requests += 1
            response = msg.trigger_response(False, "refused: not a std_srvs/srv/Trigger request")
        else:
            response = msg.trigger_response(*self._stop_unit(unit))
        query.reply(query.key_expr, response, attachment=reply_to)

    def _stop_unit(self, unit: str | None) -> tuple[bool, str]:
        """Issue the fleet's protective stop (the whole fleet, or one arm or device) and wait
        for the agents' acks."""
        self.stops += 1
        source = f"ros2:{self.inventory.principal}"
        acks = self.client.estop(
            unit, reason="ROS 2 Trigger", source=source, timeout_s=STOP_TIMEOUT_S, wait_still=False
        )
        missing = sorted(name for name, ack in acks.items() if ack is None)
        done = sorted(name for name, ack in acks.items() if ack is not None)
        if missing:
            acked = ", ".join(done) or "none"
            return False, f"stop sent; acknowledged by {acked}; no ack from {', '.join(missing)}"
        return True, f"stopped {', '.join(done)}"

    # ------------------------------------------------------------------ shutdown

    def close(self) -> None:
        """Undeclare queryables and subscriber -> stop threads -> undeclare tokens and
        publishers -> close the session if ours (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for queryable in self._queryables:
            queryable.undeclare()
        self._subscriber.undeclare()
        self._stop.set()
        self._wake.set()
        self._data.set()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout=STOP_TIMEOUT_S + 2.0)
        publishers = [self._tf, self._tf_static]
        publishers += [p for u in self.units.values() for p in u.publishers.values()]
        for p in publishers:
            p.token.undeclare()
            p.publisher.undeclare()
        for token in self._tokens:
            token.undeclare()
        if self._own_session:
            self.session.close()

    def __enter__(self) -> Ros2Node:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
