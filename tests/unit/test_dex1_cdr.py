"""The relay's hot path reads Dex1-1 state straight from serialized samples
(``codec.position_cdr``, ``codec.CDR_READERS``): it must agree with the binding's generic
deserialiser on every sample the binding writes (both families, both byte orders, XCDR1 and
plain XCDR2), and refuse anything else with ``BadSample`` or ``UnsupportedEncoding``, never
another exception."""

from __future__ import annotations

import contextlib
import math

import pytest
from cyclonedds.idl._support import Endianness
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.dex1 import codec, idl

F32 = st.floats(-1.0, 7.0, width=32)
ANY32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
ENCODINGS = [(e, v2) for e in (Endianness.Little, Endianness.Big) for v2 in (False, True)]


def _go(q: float, dq: float, tau: float, temp: int, lost: int, motors: int) -> idl.MotorStates_:
    motor = idl.GoMotorState_(mode=1, q=q, dq=dq, tau_est=tau, temperature=temp, lost=lost)
    return idl.MotorStates_(states=[motor] * motors)


def _hg(
    q: float, dq: float, tau: float, temps: list[int], bits: int, err: int, presses: int
) -> idl.HandState_:
    motor = idl.HgMotorState_(q=q, dq=dq, tau_est=tau, temperature=temps, motorstate=bits)
    return idl.HandState_(
        motor_state=[motor],
        press_sensor_state=[idl.PressSensorState_(lost=7)] * presses,
        power_v=24.0,
        error=[err, 3],
    )


def _same(fast: codec.Reading | Exception, slow: codec.Reading | Exception) -> None:
    if isinstance(slow, Exception):
        assert isinstance(fast, codec.BadSample), (fast, slow)
    else:
        assert fast == slow


def _try(read, sample):  # type: ignore[no-untyped-def]
    try:
        return read(sample)
    except codec.BadSample as exc:
        return exc


@settings(max_examples=150, deadline=None)
@given(
    q=ANY32, dq=F32, tau=F32, temp=st.integers(0, 255), lost=st.integers(0, 2**32 - 1),
    motors=st.integers(0, 6), encoding=st.sampled_from(ENCODINGS),
)  # fmt: skip
def test_go_state_read_from_bytes_equals_the_binding(  # type: ignore[no-untyped-def]
    q, dq, tau, temp, lost, motors, encoding
) -> None:
    sample = _go(q, dq, tau, temp, lost, motors)
    data = sample.serialize(endianness=encoding[0], use_version_2=encoding[1])
    _same(_try(codec.reading_from_go_cdr, data), _try(codec.reading_from_go, sample))
    position = _try(lambda d: codec.position_cdr(d, "go"), data)
    if isinstance(position, float):
        assert position == idl.MotorStates_.deserialize(data).states[0].q
    else:
        assert motors not in range(1, 5) or not math.isfinite(q) or not -1 <= q <= 7.3


@settings(max_examples=150, deadline=None)
@given(
    q=ANY32, dq=F32, tau=F32, temps=st.lists(st.integers(-300, 300), min_size=2, max_size=2),
    bits=st.integers(0, 2**32 - 1), err=st.integers(0, 2**32 - 1), presses=st.integers(0, 3),
    encoding=st.sampled_from(ENCODINGS),
)  # fmt: skip
def test_hg_state_read_from_bytes_equals_the_binding(  # type: ignore[no-untyped-def]
    q, dq, tau, temps, bits, err, presses, encoding
) -> None:
    sample = _hg(q, dq, tau, temps, bits, err, presses)
    data = sample.serialize(endianness=encoding[0], use_version_2=encoding[1])
    _same(_try(codec.reading_from_hg_cdr, data), _try(codec.reading_from_hg, sample))
    position = _try(lambda d: codec.position_cdr(d, "hg"), data)
    assert isinstance(position, float) == (math.isfinite(q) and -1 <= q <= 2 * math.pi + 1)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400), st.sampled_from(["go", "hg"]))
def test_hostile_bytes_are_refused_never_crash(data: bytes, family: str) -> None:
    for read in (codec.CDR_READERS[family], lambda d: codec.position_cdr(d, family)):
        with contextlib.suppress(codec.BadSample, codec.UnsupportedEncoding):
            read(data)


@pytest.mark.parametrize("family", ["go", "hg"])
def test_truncated_and_overlong_lists_are_bad_samples(family: str) -> None:
    sample = _go(1.0, 0, 0, 30, 0, 1) if family == "go" else _hg(1.0, 0, 0, [1, 2], 0, 0, 1)
    data = sample.serialize()
    assert codec.CDR_READERS[family](data).q_rad == 1.0
    for cut in range(len(data) - 1, 0, -7):
        with pytest.raises(codec.BadSample):
            codec.CDR_READERS[family](data[:cut])
    huge = data[:4] + (10**6).to_bytes(4, "little") + data[8:]
    with pytest.raises(codec.BadSample):
        codec.CDR_READERS[family](huge)
    with pytest.raises(codec.UnsupportedEncoding):
        codec.CDR_READERS[family](b"\x00\x0b\x00\x00" + data[4:])
