"""The agent's hot path, piece by piece: the ArmString_ sample decoder, the typed decode of an
angle report, and the WaitSet that names the readers with data (on a real DDS participant)."""

from __future__ import annotations

import json
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fleet.d1 import dds
from fleet.d1 import protocol as p
from fleet.d1.errors import MalformedMessage

# ----------------------------------------------------------------------------- samples


@given(st.text(max_size=300))
def test_a_sample_decodes_to_the_bytes_the_binding_would_give(text: str) -> None:
    if "\x00" in text:
        return  # a CDR string ends at its NUL: no writer can send one inside
    serialized = dds.ArmString_(text).serialize()
    assert dds.arm_string_bytes(serialized) == text.encode()


@given(st.text(max_size=300), st.booleans())
def test_a_command_serializes_byte_for_byte_as_the_binding_writes_it(
    text: str, version_2: bool
) -> None:
    if "\x00" in text:
        return
    binding = dds.ArmString_(text).serialize(use_version_2=version_2)
    assert dds.arm_string_sample(text, version_2) == binding.ljust((len(binding) + 3) & ~3, b"\0")


@pytest.mark.parametrize("header", [b"\x00\x00\x00\x00", b"\x00\x06\x00\x00"])
def test_big_endian_and_xcdr2_samples_decode(header: bytes) -> None:
    serialized = header + struct.pack(">I", 4) + b"abc\x00"
    assert dds.arm_string_bytes(serialized) == b"abc"
    assert dds.ArmString_.deserialize(serialized).data_ == "abc"


@pytest.mark.parametrize(
    "serialized",
    [
        b"",
        b"\x00\x01\x00\x00",
        b"\x00\x01\x00\x00" + struct.pack("<I", 1_000_000) + b"abc\x00",  # length past the end
        b"\x00\x01\x00\x00" + struct.pack("<I", 4) + b"abcd",  # no NUL
        b"\x00\x01\x00\x00" + struct.pack("<I", 0),  # no room for the NUL
    ],
)
def test_a_hostile_sample_is_a_value_error(serialized: bytes) -> None:
    with pytest.raises(ValueError, match="not an ArmString_"):
        dds.arm_string_bytes(serialized)


def test_invalid_utf8_is_left_to_the_codec_which_calls_it_malformed() -> None:
    serialized = b"\x00\x01\x00\x00" + struct.pack("<I", 3) + b"\xff\xfe\x00"
    assert dds.arm_string_bytes(serialized) == b"\xff\xfe"
    with pytest.raises(MalformedMessage):
        p.decode_message(b"\xff\xfe")


# ----------------------------------------------------------------------------- typed decode

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
numbers = st.one_of(finite, st.integers(-(10**20), 10**20))


def _generic(text: str) -> p.Decoded:
    """What the generic path alone says of ``text``."""
    seq, address, funcode, data, unknown = p._parse_envelope(text)
    assert (address, funcode) == (p.REPORT_ADDRESS, 1)
    angles = tuple(p._read_number(data, k) for k in p._ANGLE_KEYS)
    unknown.extend(p._unknown_data(data, p._ANGLE_KEYS))
    return p.Decoded(p.JointAngles(angles), seq, tuple(unknown))


@given(st.lists(numbers, min_size=7, max_size=7), st.integers(0, 2**31), st.booleans())
def test_the_typed_angle_decode_agrees_with_the_generic_one(
    angles: list[float], seq: int, extra_field: bool
) -> None:
    data: dict[str, object] = {f"angle{i}": a for i, a in enumerate(angles)}
    if extra_field:
        data["torque0"] = 1  # a newer firmware's field: the generic path reports it
    text = json.dumps({"seq": seq, "address": 2, "funcode": 1, "data": data})
    assert p.decode_message(text) == _generic(text)


@pytest.mark.parametrize(
    "data",
    [
        {**{f"angle{i}": 0 for i in range(7)}, "angle3": True},
        {**{f"angle{i}": 0 for i in range(7)}, "angle3": "1"},
        {f"angle{i}": 0 for i in range(6)},
        {**{f"angle{i}": 0 for i in range(7)}, "angle3": 10**400},
    ],
)
def test_an_odd_angle_report_gets_the_generic_paths_error(data: dict[str, object]) -> None:
    with pytest.raises(MalformedMessage, match="angle"):
        p.decode_message(json.dumps({"seq": 1, "address": 2, "funcode": 1, "data": data}))


# ----------------------------------------------------------------------------- the WaitSet
