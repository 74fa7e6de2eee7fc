"""The fuzz targets' properties (``fuzz/``), kept honest without atheris.

Each target's seed corpus is replayed through its ``check`` (so a target cannot rot without
``make test`` noticing), and hypothesis drives the same properties briefly: a command that
``decode_command`` returns is valid, every key-space kind gives its Struct or PayloadError,
and ``plan`` never lets an out-of-range D1 command through. ``make fuzz`` runs them for real.
"""

from __future__ import annotations

import importlib
import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fuzz import TARGETS, agent_plan, d1_command, keyspace, quick

QUICK_SECONDS = 2.0
"""Per target in ``make test`` (``make fuzz`` runs them for minutes, coverage-guided)."""

QUICK = settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)


@pytest.mark.parametrize("target", TARGETS)
def test_every_seed_satisfies_its_target(target: str) -> None:
    module = importlib.import_module(f"fuzz.{target}")
    seeds = module.seeds()
    assert seeds, f"fuzz.{target} has no seeds"
    for seed in seeds:
        module.check(seed)


NUMBERS = (
    st.integers(min_value=-(10**30), max_value=10**30)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.sampled_from([0, 1, 6, 7, 65, 65.0001, 80000, 80001, -1, 135, 135.5, 1e308, -0.0])
)
ANGLE_KEYS = [f"angle{i}" for i in range(7)]


@QUICK
@given(
    seq=st.integers(min_value=-2, max_value=70000),
    funcode=st.integers(min_value=0, max_value=8),
    data=st.dictionaries(
        st.sampled_from(["id", "angle", "delay_ms", "mode", "power", *ANGLE_KEYS]), NUMBERS
    ),
)
def test_a_decoded_d1_command_is_always_valid(seq: int, funcode: int, data: dict) -> None:
    text = json.dumps({"seq": seq, "address": 1, "funcode": funcode, "data": data})
    d1_command.check(text.encode())


JSON_SCALARS = st.none() | st.booleans() | NUMBERS | st.text(max_size=10)
FIELDS = st.sampled_from(
    [
        "op",
        "joint",
        "angle_deg",
        "angles_deg",
        "mode",
        "on",
        "strength",
        "stamp_ns",
        "source",
        "stop_id",
        "arms",
        "target",
        "command",
        "seq",
        "link",
    ]
)
JSON = st.recursive(
    JSON_SCALARS,
    lambda inner: st.lists(inner, max_size=8) | st.dictionaries(FIELDS, inner, max_size=6),
    max_leaves=16,
)


@QUICK
@given(JSON)
def test_every_keyspace_kind_gives_its_struct_or_a_payload_error(value: object) -> None:
    keyspace.check(json.dumps(value).encode())


OPS = st.sampled_from(["move_joint", "move_joints", "torque", "power", "zero", "hold", "release"])
ANGLES = st.lists(NUMBERS, min_size=6, max_size=8)


@QUICK
@given(
    state=st.integers(min_value=0, max_value=255),
    measured=st.binary(min_size=7, max_size=7),
    op=OPS,
    fields=st.fixed_dictionaries(
        {},
        optional={
            "joint": st.none() | st.integers(min_value=-1, max_value=7),
            "angle_deg": NUMBERS,
            "angles_deg": ANGLES,
            "mode": st.integers(min_value=-1, max_value=2),
            "on": st.booleans(),
            "strength": st.none() | st.integers(min_value=-1, max_value=80001),
            "start_at_ns": st.none() | st.integers(min_value=0, max_value=2**63 - 1),
        },
    ),
)
def test_plan_never_lets_an_out_of_range_command_through(
    state: int, measured: bytes, op: str, fields: dict
) -> None:
    payload = json.dumps({"op": op, **fields}).encode()
    agent_plan.check(bytes([state]) + measured + payload)


@pytest.mark.parametrize("target", TARGETS)
def test_every_target_survives_a_short_mutation_run(target: str) -> None:
    """Issue 28: the targets run in ``make test`` (a few seconds each, no atheris), so an
    invariant that the product outgrew fails CI, not the next ``make fuzz``."""
    result = quick.run_target(target, QUICK_SECONDS)
    assert result.failure is None, f"fuzz.{target}: {result.failure}"
    assert result.inputs > 100, result


def test_the_seeds_cover_every_kind_of_the_product() -> None:
    """Every payload of the channel table decodes one keyspace seed (device rows included), and
    the inventory seeds hold a devices-only inventory and one with arms and devices."""
    from fleet.inventory import parse_inventory
    from fleet.wire import payloads
    from fuzz import inventory

    seeds = keyspace.seeds()

    def decodes(kind: payloads.PayloadKind) -> bool:  # type: ignore[type-arg]
        for seed in seeds:
            try:
                kind.decode(seed)
            except payloads.PayloadError:
                continue
            return True
        return False

    assert [c.kind for c in payloads.CHANNELS.values() if not decodes(c.payload)] == []
    parsed = [parse_inventory(s.decode(), "seed.toml") for s in inventory.seeds()]
    assert any(i.devices and not i.arms for i in parsed)
    assert any(i.devices and i.arms for i in parsed)
