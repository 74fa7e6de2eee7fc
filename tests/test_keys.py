"""The key space: builders and the parser agree, and names that cannot be in a key are refused."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fleet.wire import keys
from fleet.wire.keys import ArmKey, KeyError_, KeySpace

NAMES = st.from_regex(r"[A-Za-z0-9][A-Za-z0-9_\-]{0,62}", fullmatch=True)


def test_builders_spell_the_documented_keys() -> None:
    ks = KeySpace("lab")
    assert ks.arm("a1", keys.JOINTS) == "fleet/lab/arm/a1/joints"
    assert ks.arm("a1", keys.RAW_COMMAND) == "fleet/lab/arm/a1/raw/command"
    assert ks.arm("a1", keys.ESTOP_ACK) == "fleet/lab/arm/a1/estop/ack"
    assert ks.arm("a1", keys.SIM_FAULT) == "fleet/lab/arm/a1/sim/fault"
    assert ks.all_arms(keys.STATUS) == "fleet/lab/arm/*/status"
    assert ks.state == "fleet/lab/state"
    assert ks.estop == "fleet/lab/estop"
    assert ks.reset == "fleet/lab/reset"
    assert ks.heartbeat == "fleet/lab/heartbeat/*"
    assert ks.heartbeat_of("coordinator") == "fleet/lab/heartbeat/coordinator"
    assert ks.command("a1", "ann") == "fleet/lab/arm/a1/cmd/ann"
    assert ks.commands("a1") == "fleet/lab/arm/a1/cmd/*"
    assert ks.principal_of("fleet/lab/arm/a1/cmd/ann") == "ann"
    assert ks.principal_of("fleet/lab/heartbeat/coordinator") == "coordinator"
    assert ks.everything == "fleet/lab/**"


@pytest.mark.parametrize("channel", keys.ARM_CHANNELS)
def test_every_channel_round_trips(channel: str) -> None:
    ks = KeySpace("lab")
    assert ks.parse_arm_key(ks.arm("arm-7_b", channel)) == ArmKey("lab", "arm-7_b", channel)


@given(fleet=NAMES, arm=NAMES, channel=st.sampled_from(keys.ARM_CHANNELS))
def test_round_trip(fleet: str, arm: str, channel: str) -> None:
    ks = KeySpace(fleet)
    key = ks.arm(arm, channel)
    assert ks.parse_arm_key(key) == ArmKey(fleet, arm, channel)


BAD_NAMES = [
    "",
    "a/b",
    "a*",
    "*",
    "**",
    "$x",
    "a$",
    "a b",
    " a",
    "a1\n",
    "a\t1",
    "-a",
    "_a",
    "a.b",
    "a?",
    "a#",
    "é",
    "a" * 64,
]


@pytest.mark.parametrize("name", BAD_NAMES)
def test_bad_names_are_refused(name: str) -> None:
    with pytest.raises(KeyError_, match="not usable in a key"):
        keys.check_name("arm", name)
    with pytest.raises(KeyError_):
        KeySpace(name)
    if name != "*":
        with pytest.raises(KeyError_):
            KeySpace("lab").arm(name, keys.JOINTS)


def test_longest_name_is_accepted() -> None:
    assert keys.check_name("arm", "a" * 63) == "a" * 63


def test_unknown_channel_is_refused() -> None:
    with pytest.raises(KeyError_, match="unknown arm channel"):
        KeySpace("lab").arm("a1", "joint")


@pytest.mark.parametrize(
    "key",
    [
        "fleet/other/arm/a1/joints",
        "fleet/lab/arm/a1/unknown",
        "fleet/lab/arm/a1",
        "fleet/lab/arm/a1/",
        "fleet/lab/arm//joints",
        "fleet/lab/arm/*/joints",
        "fleet/lab/arm/a1/joints/extra",
        "fleet/lab/state",
        "fleet/lab",
        "fleet/labx/arm/a1/joints",
        "xfleet/lab/arm/a1/joints",
        "fleet/lab/arm/a1\n/joints",
        "",
    ],
)
def test_parser_refuses_foreign_keys(key: str) -> None:
    with pytest.raises(KeyError_):
        KeySpace("lab").parse_arm_key(key)


def test_key_error_is_a_value_error_not_the_builtin() -> None:
    assert issubclass(KeyError_, ValueError)
    assert not issubclass(KeyError_, KeyError)
