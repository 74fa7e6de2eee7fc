"""``fleet ros2`` end to end (issue 27): real router, simulated arm, agent and ``fleet ros2``
processes; on the other side a ROS 2 peer written from ros2/rmw_zenoh's docs/design.md, with
keys assembled by pamoja-ros2 and CDR read by rosbags (neither is our code). It checks the key,
the tokens, the attachment and the CDR of every sample, gets ``robot_description`` as a late
joiner from the publisher's cache, and calls the Trigger stop services, well and badly."""

from __future__ import annotations

import math
import struct
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
import zenoh
import zenoh.ext
from pamoja import ros2 as pamoja

from fleet.wire import keys, payloads
from fleet.wire.session import open_client
from testkit.harness import FleetHarness, wait_until
from testkit.ros2_types import PUBLIC_HASHES, STORE

URDF = Path(__file__).resolve().parents[2] / "fleet" / "scene3d" / "assets" / "d1_550.urdf"
TRIGGER_RESPONSE = "std_srvs/msg/TriggerResponse"  # registered by test_ros2_contract
MOVING_JOINTS = [
    j.get("name") for j in ET.parse(URDF).getroot().iter("joint") if j.get("type") != "fixed"
]
MOVING_LINKS = [
    (j.find("parent").get("link"), j.find("child").get("link"))  # type: ignore[union-attr]
    for j in ET.parse(URDF).getroot().iter("joint")
    if j.get("type") != "fixed"
]


def ros_key(fqn: str, ros_type: str, domain: int = 0) -> str:
    """The data key as pamoja-ros2 assembles it, with the public hash of the type."""
    key = pamoja.entity_key(domain, fqn, ros_type, f"RIHS01_{PUBLIC_HASHES[ros_type]}")
    assert key is not None
    return key


def attachment(sample: Any) -> tuple[int, int, bytes]:
    """(sequence, source timestamp, GID) read as design.md spells the 33 bytes."""
    raw = sample.attachment.to_bytes()
    assert len(raw) == 33, raw
    seq, stamp, size = struct.unpack_from("<qqB", raw)
    assert size == 16
    return seq, stamp, raw[17:]


def parse_token(token: str) -> dict[str, str]:
    """A liveliness token split as design.md's table names its parts."""
    names = ["admin", "domain", "zid", "nid", "id", "kind", "enclave", "ns", "node"]
    names += ["topic", "type", "hash", "qos"]
    parts = token.split("/")
    assert parts[0] == "@ros2_lv" and len(parts) in (9, 13), token
    return dict(zip(names, parts, strict=False))


class Collector:
    """Samples of one key, kept with the time they arrived."""

    def __init__(self) -> None:
        self.samples: list[Any] = []
        self.lock = threading.Lock()

    def __call__(self, sample: Any) -> None:
        with self.lock:
            self.samples.append(sample)

    def count(self) -> int:
        with self.lock:
            return len(self.samples)


def call(session: zenoh.Session, key: str, payload: bytes | None, attach: bytes | None) -> list:
    """One service call as rmw_zenoh's client makes it; the replies within 5 s."""
    options: dict[str, Any] = {"target": zenoh.QueryTarget.ALL_COMPLETE, "timeout": 5.0}
    if payload is not None:
        options["payload"] = payload
    if attach is not None:
        options["attachment"] = attach
    return [r for r in session.get(key, **options)]


def test_fleet_on_rmw_zenohs_wire(tmp_path: Path) -> None:
    extra = '[ros2]\nestop_callers = ["operator"]\n'
    with FleetHarness(tmp_path, arms=2, extra=extra) as harness:
        client = harness.start_fleet()
        ros2 = harness.start("ros2", ["-m", "fleet.cli.main", "ros2"])
        peer = open_client([harness.endpoint])
        try:
            _check(harness, client, peer, ros2)
        finally:
            peer.close()


def _check(harness: FleetHarness, client: Any, peer: zenoh.Session, ros2: Any) -> None:
    # Tokens: ros2 node list / topic list see a node per arm and its publishers.
    def tokens() -> list[str]:
        return [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**") if r.ok]

    def complete() -> list[str] | None:
        found = tokens()
        return found if sum("/MP/" in t for t in found) >= 8 else None

    found = wait_until(complete, 30.0)
    parsed = [parse_token(t) for t in found]
    nodes = {(p["ns"], p["node"]) for p in parsed if p["kind"] == "NN"}
    assert {("%test%a1", "d1_fleet"), ("%test%a2", "d1_fleet"), ("%test", "d1_fleet")} <= nodes
    pubs = {p["topic"]: p for p in parsed if p["kind"] == "MP"}
    js = pubs["%test%a1%joint_states"]
    assert js["type"] == "sensor_msgs::msg::dds_::JointState_"
    assert js["hash"] == f"RIHS01_{PUBLIC_HASHES['sensor_msgs/msg/JointState']}"
    assert pubs["%test%a1%robot_description"]["qos"] == ":1:,1:,:,:,,"  # transient local, 1
    assert pubs["%tf_static"]["qos"] == ":1:,1:,:,:,,"
    services = {p["topic"] for p in parsed if p["kind"] == "SS"}
    assert {"%test%estop", "%test%a1%estop", "%test%a2%estop"} <= services
    assert all(p["nid"] != "" and p["zid"] == parsed[0]["zid"] for p in parsed)

    # joint_states: every sample checked, against the fleet's own joints key.
    js_samples, joints = Collector(), Collector()
    subs = [
        peer.declare_subscriber(
            ros_key("/test/a1/joint_states", "sensor_msgs/msg/JointState"), js_samples
        ),
        peer.declare_subscriber(f"fleet/test/arm/a1/{keys.JOINTS}", joints),
    ]
    wait_until(lambda: js_samples.count() >= 20, 20.0)
    for sub in subs:
        sub.undeclare()
    fleet_joints = {}
    for s in joints.samples:
        j = payloads.JOINTS.decode(s.payload.to_bytes())
        fleet_joints[j.stamp_ns] = j.angles_deg
    seqs, gids = [], set()
    matched = 0
    for sample in js_samples.samples:
        seq, stamp, gid = attachment(sample)
        seqs.append(seq)
        gids.add(gid)
        assert sample.payload.to_bytes()[:4] == b"\x00\x01\x00\x00"
        msg = STORE.deserialize_cdr(sample.payload.to_bytes(), "sensor_msgs/msg/JointState")
        assert list(msg.name) == MOVING_JOINTS
        sample_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        assert stamp == sample_ns  # the source timestamp is the sample's time
        if sample_ns in fleet_joints:
            matched += 1
            angles = fleet_joints[sample_ns]
            for i in range(6):
                assert math.isclose(msg.position[i], math.radians(angles[i]), abs_tol=1e-12)
    assert matched >= 10, (matched, len(js_samples.samples))
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))) and len(gids) == 1

    # /tf: each joints sample's moving joints, parent -> child as the URDF names them.
    tf_samples = Collector()
    sub = peer.declare_subscriber(ros_key("/tf", "tf2_msgs/msg/TFMessage"), tf_samples)
    wait_until(lambda: tf_samples.count() >= 4, 10.0)
    sub.undeclare()
    last: dict[str, tuple[int, bytes]] = {}
    for sample in tf_samples.samples:
        tf = STORE.deserialize_cdr(sample.payload.to_bytes(), "tf2_msgs/msg/TFMessage")
        arm = tf.transforms[0].header.frame_id.split("/")[0]
        edges = [(t.header.frame_id, t.child_frame_id) for t in tf.transforms]
        assert edges == [(f"{arm}/{p}", f"{arm}/{c}") for p, c in MOVING_LINKS]
        stamp = tf.transforms[0].header.stamp
        stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        assert attachment(sample)[1] == stamp_ns
        # Sent when the arm moved, else once a second (tf2 keeps 10 s: RViz never loses it).
        poses = b"".join(
            struct.pack(
                "<7d",
                *(getattr(t.transform.translation, a) for a in "xyz"),
                *(getattr(t.transform.rotation, a) for a in "xyzw"),
            )
            for t in tf.transforms
        )
        if arm in last and last[arm][1] == poses:
            assert stamp_ns - last[arm][0] >= 1_000_000_000, "an unchanged /tf within a second"
        last[arm] = (stamp_ns, poses)

    # A late joiner gets robot_description and tf_static from the publishers' caches.
    late, late_tf = Collector(), Collector()
    history = zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1)
    late_subs = [
        zenoh.ext.declare_advanced_subscriber(
            peer,
            ros_key("/test/a2/robot_description", "std_msgs/msg/String"),
            late,
            history=history,
        ),
        zenoh.ext.declare_advanced_subscriber(
            peer, ros_key("/tf_static", "tf2_msgs/msg/TFMessage"), late_tf, history=history
        ),
    ]
    wait_until(lambda: late.count() >= 1 and late_tf.count() >= 1, 10.0)
    for sub in late_subs:
        sub.undeclare()
    urdf = STORE.deserialize_cdr(late.samples[0].payload.to_bytes(), "std_msgs/msg/String").data
    assert urdf == URDF.read_text()
    assert attachment(late.samples[0])[0] == 1
    tf = STORE.deserialize_cdr(late_tf.samples[0].payload.to_bytes(), "tf2_msgs/msg/TFMessage")
    bases = {t.child_frame_id: t for t in tf.transforms if t.header.frame_id == "world"}
    assert set(bases) == {"a1/base_link", "a2/base_link"}
    # the fixed joints are static too (robot_state_publisher's way); the moving ones are /tf
    static_children = {t.child_frame_id for t in tf.transforms}
    assert not static_children & {f"a1/{child}" for _p, child in MOVING_LINKS}
    assert bases["a2/base_link"].header.frame_id == "world"
    assert math.isclose(bases["a2/base_link"].transform.translation.y, 0.6)

    # diagnostics, once a second per arm.
    diags = Collector()
    sub = peer.declare_subscriber(
        ros_key("/test/a1/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"), diags
    )
    wait_until(lambda: diags.count() >= 1, 5.0)
    sub.undeclare()
    arr = STORE.deserialize_cdr(
        diags.samples[0].payload.to_bytes(), "diagnostic_msgs/msg/DiagnosticArray"
    )
    assert arr.status[0].hardware_id == "a1" and arr.status[0].level == 0
    assert "relayed" in {v.key for v in arr.status[0].values}

    # Forged tokens (our node's own, a forged service) change nothing of ours.
    zid = parsed[0]["zid"]
    forged = [
        peer.liveliness().declare_token(f"@ros2_lv/0/{zid}/1/1/NN/%/%test/d1_fleet"),
        peer.liveliness().declare_token(
            f"@ros2_lv/0/{zid}/9/9/SS/%/%test/d1_fleet/%test%estop/"
            "std_srvs::srv::dds_::Trigger_/RIHS01_00/::,10:,:,:,,"
        ),
    ]

    # The Trigger service: garbage is refused or ignored, the process lives on.
    estop = ros_key("/test/estop", "std_srvs/srv/Trigger")
    gid = bytes(range(16))
    good = struct.pack("<qqB16s", 7, time.time_ns(), 16, gid)
    request = b"\x00\x01\x00\x00\x00"  # CDR header + the empty request's placeholder octet
    assert call(peer, estop, request, None) == []  # no attachment: ignored, nothing to reply to
    assert call(peer, estop, request, b"\x01\x02") == []  # malformed attachment
    refused = call(peer, estop, b"garbage", good)
    assert len(refused) == 1 and refused[0].ok is not None
    answer = STORE.deserialize_cdr(refused[0].ok.payload.to_bytes(), TRIGGER_RESPONSE)
    assert answer.success is False and answer.message.startswith("refused")
    assert call(peer, estop, None, good)[0].ok is not None
    assert ros2.poll() is None, harness.log("ros2")

    # A real request stops arm a1 (its own service), answered with the client's seq and GID.
    replies = call(peer, ros_key("/test/a1/estop", "std_srvs/srv/Trigger"), request, good)
    assert len(replies) == 1 and replies[0].ok is not None, harness.log("ros2")
    seq, _stamp, reply_gid = attachment(replies[0].ok)
    assert (seq, reply_gid) == (7, gid)
    reply = STORE.deserialize_cdr(replies[0].ok.payload.to_bytes(), TRIGGER_RESPONSE)
    assert reply.success, (reply, harness.log("ros2"))
    assert reply.message.startswith("stopped a1")
    status = wait_until(lambda: (s := client.snapshot(["a1"])["a1"][0]) and s.estopped and s, 5.0)
    assert status.stop_reason is not None
    assert client.snapshot(["a2"])["a2"][0].estopped is False
    for token in forged:
        token.undeclare()
    assert ros2.poll() is None, harness.log("ros2")


# Unitree's g1_29dof URDF (unitree_ros, mujoco-menagerie): its joints in rt/lowstate's motor
# order, written out here rather than taken from fleet/.
G1_29DOF_JOINTS = [
    "left_hip_pitch_joint",
    "left_hip_roll_joint",
    "left_hip_yaw_joint",
    "left_knee_joint",
    "left_ankle_pitch_joint",
    "left_ankle_roll_joint",
    "right_hip_pitch_joint",
    "right_hip_roll_joint",
    "right_hip_yaw_joint",
    "right_knee_joint",
    "right_ankle_pitch_joint",
    "right_ankle_roll_joint",
    "waist_yaw_joint",
    "waist_roll_joint",
    "waist_pitch_joint",
    "left_shoulder_pitch_joint",
    "left_shoulder_roll_joint",
    "left_shoulder_yaw_joint",
    "left_elbow_joint",
    "left_wrist_roll_joint",
    "left_wrist_pitch_joint",
    "left_wrist_yaw_joint",
    "right_shoulder_pitch_joint",
    "right_shoulder_roll_joint",
    "right_shoulder_yaw_joint",
    "right_elbow_joint",
    "right_wrist_roll_joint",
    "right_wrist_pitch_joint",
    "right_wrist_yaw_joint",
]
DEVICES = '[ros2]\n\n[grippers.gl]\nmount = "a1"\n\n[g1.h1]\n'


def test_devices_publish_their_own_joint_states(tmp_path: Path) -> None:
    """The Dex1-1 (gripper/gl/state) and the G1 (g1/h1/lowstate) as ROS joint_states: every
    sample's key, token, attachment and CDR, its values those of the fleet's own key."""
    with FleetHarness(tmp_path, arms=1, extra=DEVICES) as harness:
        harness.start_router()
        harness.start_sim()
        harness.start("devices", ["-m", "edge_agent", "--device", "gl", "--device", "h1"])
        harness.start("ros2", ["-m", "fleet.cli.main", "ros2"])
        peer = open_client([harness.endpoint])
        try:
            _check_devices(peer)
        finally:
            peer.close()


def _check_devices(peer: zenoh.Session) -> None:
    def publishers() -> dict[str, dict[str, str]] | None:
        found = [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**") if r.ok]
        pubs = {p["topic"]: p for p in map(parse_token, found) if p["kind"] == "MP"}
        wanted = {"%test%gl%joint_states", "%test%h1%joint_states"}
        return pubs if wanted <= set(pubs) else None

    pubs = wait_until(publishers, 30.0)
    for unit in ("gl", "h1"):
        token = pubs[f"%test%{unit}%joint_states"]
        assert token["type"] == "sensor_msgs::msg::dds_::JointState_"
        assert token["hash"] == f"RIHS01_{PUBLIC_HASHES['sensor_msgs/msg/JointState']}"

    js_type = "sensor_msgs/msg/JointState"
    cases = {
        "gl": (ros_key("/test/gl/joint_states", js_type), "fleet/test/gripper/gl/state"),
        "h1": (ros_key("/test/h1/joint_states", js_type), "fleet/test/g1/h1/lowstate"),
    }
    ros = {unit: Collector() for unit in cases}
    fleet = {unit: Collector() for unit in cases}
    subs = [peer.declare_subscriber(key, ros[unit]) for unit, (key, _f) in cases.items()]
    subs += [peer.declare_subscriber(key, fleet[unit]) for unit, (_r, key) in cases.items()]
    wait_until(lambda: all(c.count() >= 12 for c in ros.values()), 30.0)
    for sub in subs:
        sub.undeclare()

    kinds = {"gl": payloads.CHANNELS["gripper/state"], "h1": payloads.CHANNELS["g1/lowstate"]}
    for unit, collector in ros.items():
        own = {}
        for s in fleet[unit].samples:
            state = kinds[unit].payload.decode(s.payload.to_bytes())
            own[state.stamp_ns] = state
        seqs, matched = [], 0
        for sample in collector.samples:
            seq, stamp, _gid = attachment(sample)
            seqs.append(seq)
            js = STORE.deserialize_cdr(sample.payload.to_bytes(), js_type)
            assert js.header.stamp.sec * 1_000_000_000 + js.header.stamp.nanosec == stamp
            if unit == "gl":
                assert list(js.name) == ["gl_joint"]
                assert len(js.velocity) == 1 and len(js.effort) == 1
            else:
                assert list(js.name) == G1_29DOF_JOINTS
                assert len(js.position) == 29 and len(js.velocity) == 0
            state = own.get(stamp)
            if state is None:
                continue
            matched += 1
            if unit == "gl":
                values = [js.position[0], js.velocity[0], js.effort[0]]
                assert values == [state.q_rad, state.dq_rad_s, state.tau_est]
            else:
                assert list(js.position) == state.q_rad
        assert matched >= 6, (unit, matched, len(collector.samples))
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))


def test_humble_keys_and_tokens_carry_no_type_hash(tmp_path: Path) -> None:
    """``[ros2] distro = "humble"``: the tokens and the keys say ``TypeHashNotSupported``, and a
    late joiner gets robot_description from the cache on that key."""
    with FleetHarness(tmp_path, arms=1, extra='[ros2]\ndistro = "humble"\n') as harness:
        harness.start_router()
        harness.start("ros2", ["-m", "fleet.cli.main", "ros2"])
        peer = open_client([harness.endpoint])
        try:

            def publishers() -> list[dict[str, str]] | None:
                found = [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**") if r.ok]
                parsed = [parse_token(t) for t in found if "/MP/" in t or "/SS/" in t]
                return parsed if len(parsed) >= 7 else None  # tf, tf_static, 3 + 2 services

            for token in wait_until(publishers, 30.0):
                assert token["hash"] == "TypeHashNotSupported", token
            late = Collector()
            sub = zenoh.ext.declare_advanced_subscriber(
                peer,
                "0/test/a1/robot_description/std_msgs::msg::dds_::String_/TypeHashNotSupported",
                late,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            )
            wait_until(lambda: late.count() >= 1, 10.0)
            sub.undeclare()
            text = STORE.deserialize_cdr(late.samples[0].payload.to_bytes(), "std_msgs/msg/String")
            assert text.data == URDF.read_text()
        finally:
            peer.close()


@pytest.mark.timing
def test_a_stop_call_never_waits_behind_other_calls(tmp_path: Path) -> None:
    """Ten calls of a2's stop service, whose agent is down (each waits the 3 s ack timeout
    for an ack that never comes), then one of the fleet's: the fleet's stop reaches a1 at once
    and is answered within one ack timeout. Served one after another, it waited behind the ten
    (measured: 30 s before its stop was even put)."""
    extra = '[ros2]\nestop_callers = ["operator"]\n'
    with FleetHarness(tmp_path, arms=2, extra=extra) as harness:
        harness.start_router()
        harness.start_sim()
        harness.start_agent("a1")  # a2 has no agent: its stop is never acknowledged
        harness.start("ros2", ["-m", "fleet.cli.main", "ros2"])
        client = harness.client()
        wait_until(lambda: (s := client.snapshot(["a1"])["a1"][0]) and s.link == "ok", 30.0)
        peer = open_client([harness.endpoint])
        acks: list[float] = []
        sub = peer.declare_subscriber(
            f"fleet/test/arm/a1/{keys.ESTOP_ACK}", lambda _s: acks.append(time.monotonic())
        )
        try:
            _check_stop_calls_side_by_side(peer, acks)
        finally:
            sub.undeclare()
            peer.close()


def _check_stop_calls_side_by_side(peer: zenoh.Session, acks: list[float]) -> None:
    def served() -> bool:
        found = [str(r.ok.key_expr) for r in peer.liveliness().get("@ros2_lv/0/**") if r.ok]
        services = {p["topic"] for p in map(parse_token, found) if p["kind"] == "SS"}
        return {"%test%estop", "%test%a2%estop"} <= services

    wait_until(served, 30.0)
    trigger = "std_srvs/srv/Trigger"
    request = b"\x00\x01\x00\x00\x00"
    options: dict[str, Any] = {"target": zenoh.QueryTarget.ALL_COMPLETE, "timeout": 45.0}
    options["payload"] = request

    def good(seq: int) -> bytes:
        return struct.pack("<qqB16s", seq, time.time_ns(), 16, bytes(range(16)))

    slow = [
        peer.get(ros_key("/test/a2/estop", trigger), attachment=good(i), **options)
        for i in range(10)
    ]
    # Pacing: the ten calls are made before the fleet's, 0.5 s earlier (each reaches the node
    # in milliseconds; at once, the fleet's call could arrive between them on its own thread).
    time.sleep(0.5)
    started = time.monotonic()
    fleet = peer.get(ros_key("/test/estop", trigger), attachment=good(99), **options)
    replies = [r for r in fleet if r.ok is not None]
    answered_s = time.monotonic() - started
    stopped_s = (acks[0] - started) if acks else None
    print(
        f"fleet stop behind 10 calls: a1 acked after {stopped_s} s, "
        f"answered after {answered_s:.2f} s"
    )
    assert replies, "the fleet's stop call was never answered"
    answer = STORE.deserialize_cdr(replies[0].ok.payload.to_bytes(), TRIGGER_RESPONSE)
    assert "no ack from a2" in answer.message, answer
    assert stopped_s is not None and stopped_s < 1.0, stopped_s
    assert answered_s < 3.0 + 2.0, answered_s  # one ack timeout (a2's), not eleven
    for handler in slow:  # each answered, none lost
        assert [r for r in handler if r.ok is not None], "a call of a2's stop went unanswered"
