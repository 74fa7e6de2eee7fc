"""The pure D1 codec: the spec's examples byte for byte, round trips, and malformed input.

Golden strings are copied from the spec's "Command Reference Table" (../shared/seeds, the D1
service interface); every one is checked in both directions.
"""

from __future__ import annotations

import contextlib
import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fleet.d1 import protocol as p
from fleet.d1.errors import (
    InvalidCommand,
    InvalidJoint,
    MalformedMessage,
    ProtocolError,
    UnknownMessage,
)
from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG, TORQUE_MODE_MAX
from testkit.golden_d1 import GOLDEN_COMMANDS, GOLDEN_MESSAGES

# ----------------------------------------------------------------------------- golden tables


@pytest.mark.parametrize(("text", "command"), GOLDEN_COMMANDS)
def test_spec_command_encodes_byte_for_byte(text: str, command: p.Command) -> None:
    assert p.encode_command(command, seq=4) == text


@pytest.mark.parametrize(("text", "command"), GOLDEN_COMMANDS)
def test_spec_command_decodes(text: str, command: p.Command) -> None:
    seq, decoded = p.decode_command(text)
    assert seq == 4
    assert decoded == command
    assert type(decoded) is type(command)


@pytest.mark.parametrize(("text", "message"), GOLDEN_MESSAGES)
def test_spec_message_encodes_byte_for_byte(text: str, message: p.ArmMessage) -> None:
    assert p.encode_message(message) == text


@pytest.mark.parametrize(("text", "message"), GOLDEN_MESSAGES)
def test_spec_message_decodes(text: str, message: p.ArmMessage) -> None:
    decoded = p.decode_message(text)
    assert decoded == p.Decoded(message, 10, ())
    assert type(decoded.message) is type(message)
    assert p.decode_message(text.encode()) == decoded  # bytes as well as str


def test_golden_tables_cover_every_command_and_message() -> None:
    assert {type(c) for _t, c in GOLDEN_COMMANDS} == set(p.Command.__args__)  # type: ignore[attr-defined]
    assert {type(m) for _t, m in GOLDEN_MESSAGES} == set(p.ArmMessage.__args__)  # type: ignore[attr-defined]


def test_ack_carries_the_command_seq() -> None:
    text = p.encode_message(p.ReceiveAck(seq=1234, ok=False))
    assert text == '{"seq":1234,"address":3,"funcode":1,"data":{"recv_status":0}}'
    assert p.decode_message(text) == p.Decoded(p.ReceiveAck(1234, False), 1234, ())


def test_status_error_flag_is_inverted_on_the_wire() -> None:
    # error_status 1 = normal, 0 = abnormal
    text = p.encode_message(p.D1Status(enabled=False, powered=False, error_status=0))
    assert text == (
        '{"seq":10,"address":2,"funcode":3,"data":{"enable_status":0,"power_status":0,'
        '"error_status":0}}'
    )


def test_fractional_angles_are_written_as_floats() -> None:
    text = p.encode_command(p.SetJointAngle(1, -12.5), seq=7)
    assert text == '{"seq":7,"address":1,"funcode":1,"data":{"id":1,"angle":-12.5,"delay_ms":0}}'


# ----------------------------------------------------------------------------- round trips

SEQS = st.integers(min_value=0, max_value=2**31).filter(lambda s: s != p.ARM_REPORT_SEQ)
JOINTS = st.integers(min_value=0, max_value=JOINT_COUNT - 1)


def _angle(joint: int) -> st.SearchStrategy[float]:
    low, high = JOINT_RANGE_DEG[joint]
    return st.floats(min_value=low, max_value=high, allow_nan=False, allow_infinity=False)


ALL_ANGLES = st.tuples(*(_angle(j) for j in range(JOINT_COUNT)))

COMMANDS: st.SearchStrategy[p.Command] = st.one_of(
    JOINTS.flatmap(
        lambda j: st.builds(
            p.SetJointAngle,
            joint=st.just(j),
            angle_deg=_angle(j),
            delay_ms=st.integers(min_value=0, max_value=10_000),
        )
    ),
    st.builds(p.SetAllAngles, angles_deg=ALL_ANGLES, mode=st.sampled_from([0, 1])),
    st.builds(p.SetJointTorque, joint=JOINTS, enable=st.booleans()),
    st.builds(p.SetAllTorque, mode=st.integers(min_value=0, max_value=TORQUE_MODE_MAX)),
    st.builds(p.SetPower, on=st.booleans()),
    st.just(p.ReturnToZero()),
)

FINITE = st.floats(allow_nan=False, allow_infinity=False)
FLAGS7 = st.tuples(*(st.booleans() for _ in range(JOINT_COUNT)))
ACK_SEQS = st.integers(min_value=0, max_value=2**31)

MESSAGES: st.SearchStrategy[p.ArmMessage] = st.one_of(
    st.builds(p.JointAngles, angles_deg=st.tuples(*(FINITE for _ in range(JOINT_COUNT)))),
    st.builds(
        p.D1Status,
        enabled=st.booleans(),
        powered=st.booleans(),
        error_status=st.integers(*p.ERROR_STATUS_RANGE),
    ),
    st.builds(p.MotorStatus, motors_ok=FLAGS7),
    st.builds(p.ReceiveAck, seq=ACK_SEQS, ok=st.booleans()),
    st.builds(p.ExecuteAck, seq=ACK_SEQS, ok=st.booleans()),
)


@given(command=COMMANDS, seq=SEQS)
def test_command_round_trip(command: p.Command, seq: int) -> None:
    text = p.encode_command(command, seq)
    decoded_seq, decoded = p.decode_command(text)
    assert decoded_seq == seq
    assert decoded == command
    assert p.encode_command(decoded, decoded_seq) == text  # stable: a second pass is identical


@given(message=MESSAGES)
def test_arm_message_round_trip(message: p.ArmMessage) -> None:
    text = p.encode_message(message)
    decoded = p.decode_message(text)
    assert decoded.message == message
    expected_seq = message.seq if isinstance(message, (p.ReceiveAck, p.ExecuteAck)) else 10
    assert decoded.seq == expected_seq
    assert decoded.unknown_fields == ()


@given(command=COMMANDS, seq=SEQS)
def test_encoded_command_is_compact_json_without_non_finite(command: p.Command, seq: int) -> None:
    text = p.encode_command(command, seq)
    assert " " not in text
    raw = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in {text}"))
    assert list(raw)[:3] == ["seq", "address", "funcode"]


# ----------------------------------------------------------------------------- non-finite numbers

ANGLES_TEMPLATE = (
    '{"seq":10,"address":2,"funcode":1,"data":{"angle0":%s,"angle1":0,"angle2":0,'
    '"angle3":0,"angle4":0,"angle5":0,"angle6":0}}'
)


@pytest.mark.parametrize(
    "literal", ["NaN", "Infinity", "-Infinity", "nan", "inf", "1e999", "-1e999", "1" + "0" * 400]
)
def test_non_finite_feedback_is_malformed(literal: str) -> None:
    with pytest.raises(MalformedMessage):
        p.decode_message(ANGLES_TEMPLATE % literal)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "1e999", "-1e999", "1" + "0" * 400])
def test_non_finite_command_is_malformed(literal: str) -> None:
    text = f'{{"seq":4,"address":1,"funcode":1,"data":{{"id":5,"angle":{literal},"delay_ms":0}}}}'
    with pytest.raises(MalformedMessage):
        p.decode_command(text)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_angle_is_refused_on_encode(value: float) -> None:
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetJointAngle(0, value), seq=1)
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetAllAngles((0.0,) * 6 + (value,), mode=0), seq=1)
    with pytest.raises(InvalidCommand):
        p.encode_message(p.JointAngles((value,) + (0.0,) * 6))


def test_huge_integer_angle_is_refused_not_crashing() -> None:
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetJointAngle(0, 10**400), seq=1)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- joints and ranges


@pytest.mark.parametrize("joint", [-1, 7, 8, 100])
def test_out_of_range_joint_id_is_refused_on_encode(joint: int) -> None:
    with pytest.raises(InvalidJoint):
        p.encode_command(p.SetJointAngle(joint, 0.0), seq=1)
    with pytest.raises(InvalidJoint):
        p.encode_command(p.SetJointTorque(joint, True), seq=1)


def test_bool_joint_id_is_refused() -> None:
    with pytest.raises(InvalidJoint):
        p.encode_command(p.SetJointTorque(True, True), seq=1)  # type: ignore[arg-type]


@pytest.mark.parametrize("joint", [7, -1])
def test_out_of_range_joint_id_is_refused_on_decode_with_seq(joint: int) -> None:
    text = f'{{"seq":42,"address":1,"funcode":1,"data":{{"id":{joint},"angle":0,"delay_ms":0}}}}'
    with pytest.raises(InvalidJoint) as info:
        p.decode_command(text)
    assert info.value.seq == 42
    text = f'{{"seq":43,"address":1,"funcode":4,"data":{{"id":{joint},"mode":1}}}}'
    with pytest.raises(InvalidJoint) as info:
        p.decode_command(text)
    assert info.value.seq == 43


RANGES = [
    (0, -135.0, 135.0),
    (1, -90.0, 90.0),
    (2, -90.0, 90.0),
    (3, -135.0, 135.0),
    (4, -90.0, 90.0),
    (5, -135.0, 135.0),
    (6, 0.0, 65.0),
]


def test_limits_match_the_spec() -> None:
    assert [(j, lo, hi) for j, (lo, hi) in enumerate(JOINT_RANGE_DEG)] == RANGES


@pytest.mark.parametrize(("joint", "low", "high"), RANGES)
def test_angle_range_per_joint(joint: int, low: float, high: float) -> None:
    for ok in (low, high, (low + high) / 2):
        p.encode_command(p.SetJointAngle(joint, ok), seq=1)
    for bad in (low - 0.01, high + 0.01, math.nextafter(high, math.inf)):
        with pytest.raises(InvalidCommand) as info:
            p.encode_command(p.SetJointAngle(joint, bad), seq=1)
        assert not isinstance(info.value, InvalidJoint)
        angles = [0.0] * JOINT_COUNT
        angles[joint] = bad
        with pytest.raises(InvalidCommand):
            p.encode_command(p.SetAllAngles(tuple(angles), mode=1), seq=1)
        text = f'{{"seq":5,"address":1,"funcode":1,"data":{{"id":{joint},"angle":{bad!r}}}}}'
        with pytest.raises(InvalidCommand) as info:
            p.decode_command(text)
        assert info.value.seq == 5
        assert not isinstance(info.value, InvalidJoint)


def test_all_angles_needs_seven_values_and_mode_0_or_1() -> None:
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetAllAngles((0.0,) * 6), seq=1)
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetAllAngles((0.0,) * 8), seq=1)
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetAllAngles((0.0,) * 7, mode=2), seq=1)  # type: ignore[arg-type]
    text = (
        '{"seq":4,"address":1,"funcode":2,"data":{"mode":2,"angle0":0,"angle1":0,"angle2":0,'
        '"angle3":0,"angle4":0,"angle5":0,"angle6":0}}'
    )
    with pytest.raises(ProtocolError):
        p.decode_command(text)


def test_negative_delay_is_refused() -> None:
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetJointAngle(0, 0.0, delay_ms=-1), seq=1)


# ----------------------------------------------------------------------------- seq and torque


def test_seq_10_is_refused_on_encode() -> None:
    with pytest.raises(InvalidCommand, match="seq 10"):
        p.encode_command(p.ReturnToZero(), seq=10)


@pytest.mark.parametrize("seq", [-1, True, 1.5, "4"])
def test_bad_seq_is_refused_on_encode(seq: object) -> None:
    with pytest.raises(InvalidCommand):
        p.encode_command(p.ReturnToZero(), seq=seq)  # type: ignore[arg-type]


@pytest.mark.parametrize("mode", [0, 1, 2, 40000, 79999, TORQUE_MODE_MAX])
def test_all_joint_torque_mode_accepted(mode: int) -> None:
    text = p.encode_command(p.SetAllTorque(mode), seq=3)
    assert text == f'{{"seq":3,"address":1,"funcode":5,"data":{{"mode":{mode}}}}}'
    assert p.decode_command(text) == (3, p.SetAllTorque(mode))


@pytest.mark.parametrize("mode", [-1, TORQUE_MODE_MAX + 1, 10**6, True])
def test_all_joint_torque_mode_refused(mode: int) -> None:
    with pytest.raises(InvalidCommand):
        p.encode_command(p.SetAllTorque(mode), seq=3)
    if not isinstance(mode, bool):
        with pytest.raises(InvalidCommand):
            p.decode_command(f'{{"seq":3,"address":1,"funcode":5,"data":{{"mode":{mode}}}}}')


def test_encode_refuses_objects_that_are_not_commands_or_messages() -> None:
    with pytest.raises(InvalidCommand):
        p.encode_command(p.JointAngles((0.0,) * 7), seq=1)  # type: ignore[arg-type]
    with pytest.raises(InvalidCommand):
        p.encode_message(p.SetPower(True))  # type: ignore[arg-type]
    with pytest.raises(InvalidCommand):
        p.encode_message(p.JointAngles((0.0,) * 6))
    with pytest.raises(InvalidCommand):
        p.encode_message(p.MotorStatus((True,) * 6))


# ----------------------------------------------------------------------------- unknown messages


@pytest.mark.parametrize(
    ("address", "funcode"), [(2, 2), (2, 5), (3, 3), (4, 1), (0, 0), (1, 1), (1, 7)]
)
def test_unknown_address_funcode_in_feedback(address: int, funcode: int) -> None:
    text = f'{{"seq":10,"address":{address},"funcode":{funcode},"data":{{}}}}'
    with pytest.raises(UnknownMessage) as info:
        p.decode_message(text)
    assert (info.value.address, info.value.funcode) == (address, funcode)
    assert isinstance(info.value, MalformedMessage)


@pytest.mark.parametrize(("address", "funcode"), [(1, 3), (1, 8), (1, 0), (2, 1), (3, 1)])
def test_unknown_address_funcode_in_command(address: int, funcode: int) -> None:
    text = f'{{"seq":4,"address":{address},"funcode":{funcode},"data":{{}}}}'
    with pytest.raises(UnknownMessage) as info:
        p.decode_command(text)
    assert (info.value.address, info.value.funcode) == (address, funcode)
    assert info.value.seq == 4


def test_unknown_fields_are_tolerated_and_listed() -> None:
    text = (
        '{"seq":10,"address":2,"funcode":3,"stamp":17,"data":{"enable_status":1,'
        '"power_status":0,"error_status":1,"temperature":41.5,"voltage":24}}'
    )
    decoded = p.decode_message(text)
    assert decoded.message == p.D1Status(enabled=True, powered=False, error_status=1)
    assert decoded.unknown_fields == ("stamp", "data.temperature", "data.voltage")


def test_unknown_fields_on_angles_and_acks() -> None:
    angles = json.loads(GOLDEN_MESSAGES[0][0])
    angles["data"]["angle7"] = 3
    decoded = p.decode_message(json.dumps(angles))
    assert decoded.unknown_fields == ("data.angle7",)
    assert decoded.message == GOLDEN_MESSAGES[0][1]
    ack = p.decode_message('{"seq":7,"address":3,"funcode":2,"data":{"exec_status":0,"why":"x"}}')
    assert ack == p.Decoded(p.ExecuteAck(7, False), 7, ("data.why",))


def test_unknown_command_fields_are_tolerated() -> None:
    text = '{"seq":4,"address":1,"funcode":6,"extra":true,"data":{"power":0,"x":1}}'
    assert p.decode_command(text) == (4, p.SetPower(False))


# ----------------------------------------------------------------------------- malformed input

MALFORMED_FEEDBACK = [
    "",
    "   ",
    "not json",
    "[]",
    "42",
    '"text"',
    "null",
    '{"seq":10,"address":2,"funcode":1,"data":{"angle0":0',  # truncated
    b"\xff\xfe",
    # envelope fields missing or mistyped
    '{"address":2,"funcode":3,"data":{"enable_status":1,"power_status":1,"error_status":1}}',
    '{"seq":10,"funcode":3,"data":{"enable_status":1,"power_status":1,"error_status":1}}',
    '{"seq":10,"address":2,"data":{"enable_status":1,"power_status":1,"error_status":1}}',
    '{"seq":"10","address":2,"funcode":3,"data":{}}',
    '{"seq":10,"address":2.5,"funcode":3,"data":{}}',
    '{"seq":10,"address":true,"funcode":3,"data":{}}',
    '{"seq":null,"address":2,"funcode":3,"data":{}}',
    '{"seq":10,"address":2,"funcode":3,"data":[1,1,1]}',
    '{"seq":10,"address":2,"funcode":3,"data":"x"}',
    # data fields missing
    '{"seq":10,"address":2,"funcode":3}',
    '{"seq":10,"address":2,"funcode":3,"data":{"enable_status":1,"power_status":1}}',
    '{"seq":10,"address":2,"funcode":1,"data":{"angle0":0,"angle1":0,"angle2":0,"angle3":0,'
    '"angle4":0,"angle5":0}}',
    '{"seq":10,"address":3,"funcode":1,"data":{}}',
    '{"seq":10,"address":3,"funcode":2}',
    # data fields of the wrong type
    ANGLES_TEMPLATE % '"12"',
    ANGLES_TEMPLATE % "true",
    ANGLES_TEMPLATE % "null",
    ANGLES_TEMPLATE % "[1]",
    '{"seq":10,"address":3,"funcode":1,"data":{"recv_status":"1"}}',
    '{"seq":10,"address":3,"funcode":1,"data":{"recv_status":true}}',
    '{"seq":10,"address":3,"funcode":1,"data":{"recv_status":0.5}}',
    # flags other than 0/1
    '{"seq":10,"address":3,"funcode":1,"data":{"recv_status":2}}',
    '{"seq":10,"address":3,"funcode":2,"data":{"exec_status":-1}}',
    '{"seq":10,"address":2,"funcode":3,"data":{"enable_status":1,"power_status":2,'
    '"error_status":1}}',
    '{"seq":10,"address":2,"funcode":4,"data":{"motor0_status":1,"motor1_status":1,'
    '"motor2_status":1,"motor3_status":1,"motor4_status":1,"motor5_status":1,'
    '"motor6_status":3}}',
]


@pytest.mark.parametrize("text", MALFORMED_FEEDBACK)
def test_malformed_feedback(text: str | bytes) -> None:
    with pytest.raises(MalformedMessage) as info:
        p.decode_message(text)
    assert not isinstance(info.value, UnknownMessage)


MALFORMED_COMMANDS = [
    "",
    "{}",
    "[4,1,7]",
    '{"seq":4,"address":1}',
    '{"seq":4,"funcode":7}',
    '{"address":1,"funcode":7}',
    '{"seq":4.5,"address":1,"funcode":7}',
    '{"seq":4,"address":1,"funcode":1,"data":{"angle":60}}',  # id missing
    '{"seq":4,"address":1,"funcode":1,"data":{"id":5}}',  # angle missing
    '{"seq":4,"address":1,"funcode":1,"data":{"id":"5","angle":60}}',
    '{"seq":4,"address":1,"funcode":1,"data":{"id":5,"angle":"60"}}',
    '{"seq":4,"address":1,"funcode":1,"data":{"id":5.5,"angle":60}}',
    '{"seq":4,"address":1,"funcode":4,"data":{"id":5,"mode":2}}',  # flag other than 0/1
    '{"seq":4,"address":1,"funcode":4,"data":{"id":5}}',
    '{"seq":4,"address":1,"funcode":5,"data":{}}',
    '{"seq":4,"address":1,"funcode":5,"data":{"mode":"1"}}',
    '{"seq":4,"address":1,"funcode":6,"data":{"power":2}}',
    '{"seq":4,"address":1,"funcode":6,"data":{"power":true}}',
    '{"seq":4,"address":1,"funcode":6,"data":[1]}',
    '{"seq":4,"address":1,"funcode":2,"data":{"mode":1,"angle0":0}}',
]


@pytest.mark.parametrize("text", MALFORMED_COMMANDS)
def test_malformed_command(text: str) -> None:
    with pytest.raises(MalformedMessage) as info:
        p.decode_command(text)
    assert not isinstance(info.value, UnknownMessage)


def test_malformed_command_error_carries_its_seq() -> None:
    with pytest.raises(MalformedMessage) as info:
        p.decode_command('{"seq":77,"address":1,"funcode":6,"data":{"power":5}}')
    assert info.value.seq == 77


def test_integral_floats_are_tolerated_for_integers() -> None:
    # Some JSON writers emit 1.0 for 1: accepted where the spec has an integer.
    ack = p.decode_message('{"seq":12,"address":3,"funcode":1,"data":{"recv_status":1.0}}')
    assert ack.message == p.ReceiveAck(12, True)
    assert p.decode_command('{"seq":4,"address":1,"funcode":4,"data":{"id":5.0,"mode":0}}') == (
        4,
        p.SetJointTorque(5, False),
    )


@given(st.text(max_size=200))
def test_decoders_raise_only_protocol_errors_on_text(text: str) -> None:
    for decode in (p.decode_message, p.decode_command):
        with contextlib.suppress(ProtocolError):
            decode(text)


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | FINITE | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=12,
)


@given(
    seq=st.one_of(st.integers(), JSON_VALUES),
    address=st.sampled_from([1, 2, 3, 4, "2", None]),
    funcode=st.integers(min_value=0, max_value=8),
    data=st.dictionaries(
        st.sampled_from(
            ["id", "angle", "mode", "power", "angle0", "recv_status", "exec_status", "x"]
        ),
        JSON_VALUES,
    ),
)
def test_decoders_raise_only_protocol_errors_on_envelopes(
    seq: object, address: object, funcode: int, data: dict[str, object]
) -> None:
    text = json.dumps({"seq": seq, "address": address, "funcode": funcode, "data": data})
    for decode in (p.decode_message, p.decode_command):
        with contextlib.suppress(ProtocolError):
            decode(text)


# ------------------------------------------------------------------- error_status readings


@pytest.mark.parametrize(
    ("value", "error"), [(1, False), (0, True), (2, True), (0x84, True), (-1, True), (2**63, True)]
)
def test_error_status_is_any_integer_one_normal(value: int, error: bool) -> None:
    """The table reads 1 normal / 0 abnormal; the contact plan expects a bitfield: every
    integer decodes, 1 is normal, the raw value is kept, and it encodes back byte for byte."""
    text = (
        '{"seq":10,"address":2,"funcode":3,"data":{"enable_status":1,"power_status":1,'
        f'"error_status":{value}}}}}'
    )
    message = p.decode_message(text).message
    assert message == p.D1Status(enabled=True, powered=True, error_status=value)
    assert isinstance(message, p.D1Status) and message.error is error
    assert p.encode_message(message) == text


@pytest.mark.parametrize("value", ['"1"', "true", "null", "1.5", str(2**64), str(-(2**63) - 1)])
def test_error_status_that_is_no_integer_is_malformed(value: str) -> None:
    text = (
        '{"seq":10,"address":2,"funcode":3,"data":{"enable_status":1,"power_status":1,'
        f'"error_status":{value}}}}}'
    )
    with pytest.raises(MalformedMessage, match="error_status"):
        p.decode_message(text)
