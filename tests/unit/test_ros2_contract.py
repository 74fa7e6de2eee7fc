"""rmw_zenoh's contract (issue 27), pure: golden values from ros2/rmw_zenoh's docs/design.md,
and an implementation that is not ours on the other side of every check: rosbags (its
RIHS01 hashes and CDR, ROS 2 Jazzy's type store) and pamoja-ros2 (rmw_zenoh key assembly and
percent mangling)."""

from __future__ import annotations

import struct

import pytest
from pamoja import ros2 as pamoja

from fleet.ros2 import contract as c
from fleet.ros2 import messages as msg
from fleet.ros2.cdr import CdrError, CdrReader
from testkit.ros2_types import PUBLIC_HASHES, STORE

MESSAGES = [c.JOINT_STATE, c.STRING, c.TF_MESSAGE, c.DIAGNOSTIC_ARRAY]


@pytest.mark.parametrize("rtype", MESSAGES, ids=lambda t: t.name)
def test_message_hashes_are_what_rosbags_computes(rtype: c.RosType) -> None:
    assert rtype.hash == STORE.hash_rihs01(rtype.name)
    assert rtype.hash == f"RIHS01_{PUBLIC_HASHES[rtype.name]}"


def test_service_hash_is_the_public_one_and_well_formed() -> None:
    assert c.TRIGGER.hash == f"RIHS01_{PUBLIC_HASHES['std_srvs/srv/Trigger']}"
    assert pamoja.type_hash_digest(c.TRIGGER.hash) == bytes.fromhex(PUBLIC_HASHES[c.TRIGGER.name])
    assert c.TRIGGER.dds == "std_srvs::srv::dds_::Trigger_"


@pytest.mark.parametrize("fqn", ["/chatter", "/lab/a1/joint_states", "/lab/estop", "/tf_static"])
@pytest.mark.parametrize("rtype", MESSAGES, ids=lambda t: t.name)
def test_data_keys_are_pamojas(fqn: str, rtype: c.RosType) -> None:
    assert c.topic_key(0, fqn, rtype) == pamoja.entity_key(0, fqn, rtype.name, rtype.hash)
    assert c.topic_key(7, fqn, rtype) == pamoja.entity_key(7, fqn, rtype.name, rtype.hash)
    assert rtype.dds == pamoja.dds_type_name(rtype.name)
    assert c.mangle(fqn) == pamoja.percent_mangle(fqn)


def test_design_doc_examples() -> None:
    """docs/design.md's own examples, byte for byte."""
    assert (
        c.topic_key(0, "/robot1/chatter", c.STRING)
        == "0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_"
        "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
    listener = c.Node(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener")
    assert listener.token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    talker = c.Node(2, "8b20917502ee955ac4476e0266340d5c", 0, "/", "talker")
    assert talker.entity_token(10, c.PUBLISHER, "/chatter", c.STRING, c.qos_keyexpr(depth=7)) == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        "std_msgs::msg::dds_::String_/RIHS01_"
        "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
    )


def test_humble_spells_no_type_hash() -> None:
    """rmw_zenoh on Humble: ``TypeHashNotSupported`` where the RIHS01 hash goes (the form other
    rmw_zenoh peers document: ``0/chatter/std_msgs::msg::dds_::Int32_/TypeHashNotSupported``;
    pamoja-ros2 knows RIHS01 only)."""
    humble = c.for_distro(c.STRING, "humble")
    assert c.topic_key(0, "/chatter", humble) == (
        "0/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported"
    )
    node = c.Node(0, "8b20917502ee955ac4476e0266340d5c", 0, "/", "talker")
    assert node.entity_token(1, c.PUBLISHER, "/chatter", humble, "::,7:,:,:,,").endswith(
        "/%chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported/::,7:,:,:,,"
    )
    assert c.for_distro(c.STRING, "jazzy") == c.STRING


def test_qos_encoding() -> None:
    assert c.qos_keyexpr(depth=10) == "::,10:,:,:,,"
    assert c.qos_keyexpr(durability=c.TRANSIENT_LOCAL, depth=1) == ":1:,1:,:,:,,"
    assert c.qos_keyexpr(reliability=c.BEST_EFFORT, depth=1) == "2::,1:,:,:,,"
    assert c.qos_keyexpr() == "::,:,:,:,,"


def test_namespaces() -> None:
    assert c.default_namespace("lab", "a1") == "/lab/a1"
    assert c.default_namespace("my-lab", "arm-2") == "/my_lab/arm_2"
    for bad in ("lab", "/lab/", "/1lab", "/a__b", "/a/b c", "/a//b"):
        with pytest.raises(c.NameError_):
            c.check_namespace(bad)
    assert c.check_namespace("/lab/left_arm") == "/lab/left_arm"


def test_attachment_round_trip_and_refusals() -> None:
    gid = c.gid_of("@ros2_lv/0/x/0/1/MP/%/%/n/%t/T/H/::,:,:,:,,")
    data = c.Attachment(5, 1_700_000_000_000_000_000, gid).encode()
    assert len(data) == 33 and data[16] == 16
    assert struct.unpack("<q", data[:8])[0] == 5
    assert c.decode_attachment(data) == c.Attachment(5, 1_700_000_000_000_000_000, gid)
    for bad in (None, b"", data[:32], data + b"\x00", data[:16] + b"\x0f" + data[17:]):
        with pytest.raises(c.AttachmentError):
            c.decode_attachment(bad)


def test_cdr_is_what_rosbags_reads() -> None:
    names = ["Joint1", "Joint2", "Joint_L"]
    data = msg.joint_state(1_700_000_000_123_456_789, names, [0.1, -0.2, 0.033])
    assert data[:4] == b"\x00\x01\x00\x00"
    js = STORE.deserialize_cdr(data, "sensor_msgs/msg/JointState")
    assert (js.header.stamp.sec, js.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert list(js.name) == names and list(js.position) == [0.1, -0.2, 0.033]
    assert len(js.velocity) == 0 and len(js.effort) == 0
    # the same message, serialized by rosbags, is byte for byte ours
    assert STORE.serialize_cdr(js, "sensor_msgs/msg/JointState") == data

    text = "<robot name='d1'>é</robot>"
    assert STORE.deserialize_cdr(msg.string(text), "std_msgs/msg/String").data == text

    t = msg.Transform("world", "a1/base_link", (0.0, 0.6, 0.1), (0.0, 0.0, 0.7071, 0.7071))
    tf = STORE.deserialize_cdr(msg.tf_message(2_000_000_001, [t, t]), "tf2_msgs/msg/TFMessage")
    assert len(tf.transforms) == 2 and tf.transforms[1].child_frame_id == "a1/base_link"
    assert tf.transforms[0].header.frame_id == "world"
    assert tf.transforms[0].transform.rotation.w == pytest.approx(0.7071)
    assert tf.transforms[0].header.stamp.nanosec == 1

    status = msg.Status(msg.WARN, "a1", "link stale", "lab/a1", (("relayed", "12"),))
    arr = STORE.deserialize_cdr(
        msg.diagnostic_array(5, [status]), "diagnostic_msgs/msg/DiagnosticArray"
    )
    assert arr.status[0].level == 1 and arr.status[0].values[0].value == "12"

    response = msg.trigger_response(True, "stopped")
    reply = STORE.deserialize_cdr(response, "std_srvs/msg/TriggerResponse")
    assert reply.success and reply.message == "stopped"


def test_trigger_requests() -> None:
    assert msg.trigger_request_ok(msg.trigger_request())
    assert msg.trigger_request_ok(b"\x00\x01\x00\x00\x00\x00\x00\x00")  # padded to 4
    for bad in (b"", b"\x00", b"garbage!", b"\x00\x01\x00\x00", b"\x00\x01" + b"\x00" * 40):
        assert not msg.trigger_request_ok(bad)
    with pytest.raises(CdrError):
        CdrReader(b"\x00\x01\x00\x00\xff\xff\xff\x7f").string()


def test_templates_are_byte_for_byte_the_plain_writer() -> None:
    names = ["Joint1", "Joint2", "Joint_L"]
    template = msg.JointStateTemplate(names)
    for stamp, q in ((1_700_000_000_123_456_789, [0.1, -0.2, 0.033]), (5, [0.0, 1e300, -0.0])):
        assert template.message(stamp, q) == msg.joint_state(stamp, names, q)
    full = msg.JointStateTemplate(["j"], frame_id="base", velocity=True, effort=True)
    data = full.message(7, [1.0], [2.0], [3.0])
    assert data == msg.joint_state(7, ["j"], [1.0], [2.0], [3.0], frame_id="base")
    js = STORE.deserialize_cdr(data, "sensor_msgs/msg/JointState")
    assert (list(js.position), list(js.velocity), list(js.effort)) == ([1.0], [2.0], [3.0])
    with pytest.raises(ValueError):
        template.message(1)  # no positions

    frames = [("world", "a1/base_link"), ("a1/base_link", "a1/Link1"), ("a", "bcdefgh")]
    poses = [(0.1 * i, 0.2, 0.3, 0.0, 0.0, 0.6, 0.8) for i in range(3)]
    transforms = [msg.Transform(p, c_, pose[:3], pose[3:]) for (p, c_), pose in zip(frames, poses)]
    assert msg.TfTemplate(frames).message(2_000_000_001, poses) == msg.tf_message(
        2_000_000_001, transforms
    )
