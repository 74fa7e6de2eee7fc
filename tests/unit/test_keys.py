"""The key space: builders and the parser agree, and names that cannot be in a key are refused."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from fleet.wire import keys
from fleet.wire.keys import ArmKey, KeyError_, KeySpace
from fleet.wire.replies import reply_key

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


# ----------------------------------------------------------------------------- parse_key


def _all_builders(ks: KeySpace) -> list[tuple[str, keys.Key]]:
    """Every key the builders spell, with the parse the one parser must give."""
    f = ks.fleet
    out = [(ks.arm("a1", c), keys.Key(f, keys.ARM, "a1", c)) for c in keys.ARM_CHANNELS]
    out += [
        (ks.device(k, "d-1", c), keys.Key(f, k, "d-1", c))
        for k in keys.DEVICE_KINDS
        for c in keys.DEVICE_CHANNELS
    ]
    out += [
        (ks.command("a1", "ann"), keys.Key(f, keys.ARM, "a1", keys.CMD, "ann")),
        (ks.device_command("g1", "h1", "ann"), keys.Key(f, "g1", "h1", keys.CMD, "ann")),
        (ks.state, keys.Key(f, "", "", keys.STATE)),
        (ks.estop, keys.Key(f, "", "", keys.ESTOP)),
        (ks.reset, keys.Key(f, "", "", keys.RESET)),
        (ks.stop_report, keys.Key(f, "", "", keys.STOP_REPORT)),
        (ks.coordinator_diag, keys.Key(f, "", "", keys.COORDINATOR_DIAG)),
        (ks.heartbeat_of("bob"), keys.Key(f, "", "", keys.HEARTBEAT, "bob")),
        (ks.coordinator_command("bob"), keys.Key(f, "", "", keys.COORDINATOR_CMD, "bob")),
        (ks.info("agent", "host-1"), keys.Key(f, "", "agent/host-1", keys.INFO)),
    ]
    return out


def test_one_parser_reads_every_key_the_builders_spell() -> None:
    ks = KeySpace("lab")
    for key, parsed in _all_builders(ks):
        assert ks.parse_key(key) == parsed, key


@given(
    fleet=NAMES,
    unit=NAMES,
    principal=NAMES,
    kind=st.sampled_from(keys.DEVICE_KINDS),
    channel=st.sampled_from(keys.DEVICE_CHANNELS),
)
def test_device_keys_round_trip(
    fleet: str, unit: str, principal: str, kind: str, channel: str
) -> None:
    ks = KeySpace(fleet)
    assert ks.parse_key(ks.device(kind, unit, channel)) == keys.Key(fleet, kind, unit, channel)
    assert ks.parse_device_key(ks.device(kind, unit, channel), kind).device == unit
    command = ks.device_command(kind, unit, principal)
    assert ks.parse_key(command) == keys.Key(fleet, kind, unit, keys.CMD, principal)
    assert ks.principal_of(command) == principal


@pytest.mark.parametrize(
    "key",
    [
        "fleet/lab",
        "fleet/lab/",
        "fleet/other/state",
        "fleet/lab/arm/*/joints",
        "fleet/lab/arm/a1",
        "fleet/lab/arm/a1/",
        "fleet/lab/arm/a1/state",  # a device channel under an arm
        "fleet/lab/gripper/gl/joints",  # an arm channel under a device
        "fleet/lab/gripper/gl/sim/fault",
        "fleet/lab/robot/r1/state",  # no such kind
        "fleet/lab/gripper/gl/cmd/",
        "fleet/lab/gripper/gl/cmd/a/b",
        "fleet/lab/gripper/gl/cmd/*",
        "fleet/lab/heartbeat/",
        "fleet/lab/heartbeat/a/b",
        "fleet/lab/info/agent",
        "fleet/lab/state/x",
        "fleet/lab/estop/ack",
        "fleet/lab/coordinator/cmd",
        "fleet/lab/gripper/g l/state",
    ],
)
def test_parse_key_refuses_what_is_no_key(key: str) -> None:
    with pytest.raises(KeyError_):
        KeySpace("lab").parse_key(key)


def test_the_narrow_parsers_keep_to_their_kind() -> None:
    ks = KeySpace("lab")
    with pytest.raises(KeyError_):
        ks.parse_arm_key(ks.device("gripper", "gl", keys.STATE))
    with pytest.raises(KeyError_):
        ks.parse_arm_key(ks.command("a1", "ann"))
    with pytest.raises(KeyError_):
        ks.parse_device_key(ks.device("gripper", "gl", keys.STATE), "g1")
    with pytest.raises(KeyError_):
        ks.parse_device_key(ks.arm("a1", keys.CMD), "arm")
    with pytest.raises(KeyError_):
        ks.principal_of(ks.arm("a1", keys.CMD))
    with pytest.raises(KeyError_, match="unknown device kind"):
        ks.device("robot", "r1", keys.STATE)


def test_the_device_kinds_of_the_key_space_are_the_registered_ones() -> None:
    from fleet.devices import kinds

    assert sorted(kinds()) == sorted(keys.DEVICE_KINDS)


def test_a_key_of_any_fleet_parses_without_its_keyspace() -> None:
    assert keys.parse_key("fleet/other/g1/h1/state") == keys.Key("other", "g1", "h1", keys.STATE)
    for bad in ("fleet", "fleet//state", "robot/lab/state", "fleet/a b/state"):
        with pytest.raises(KeyError_):
            keys.parse_key(bad)


BASE = "fleet/lab/arm/a2/cmd"


@pytest.mark.parametrize(
    ("query", "expected"),
    [
        (f"{BASE}/alice", f"{BASE}/alice"),  # the usual case: the unit's own key
        ("fleet/lab/arm/*/cmd/alice", f"{BASE}/alice"),  # one reply per arm of a wildcard
        (f"{BASE}/*", f"{BASE}/unknown"),
        ("fleet/lab/**", f"{BASE}/unknown"),
        (f"{BASE}/bob.smith", f"{BASE}/bob.smith"),  # no usable name: the query's own key
        (f"{BASE}/b\u00f3b", f"{BASE}/b\u00f3b"),
        (f"{BASE}/{'p' * 1000}", f"{BASE}/{'p' * 1000}"),
        (f"{BASE}/bob$*", f"{BASE}/bob$*"),  # a wildcard "unknown" does not match
        ("fleet/lab/*/a2/cmd/bob.smith", "fleet/lab/*/a2/cmd/bob.smith"),
    ],
)
def test_a_reply_key_always_matches_its_query(query: str, expected: str) -> None:
    """Zenoh refuses a reply on a key that does not intersect the query's: the reply key is
    the unit's own when it matches, else the query's own (which always matches itself)."""
    key = reply_key(query, BASE)
    assert key == expected
    assert zenoh.KeyExpr(key).intersects(query)


def test_a_refusal_for_no_principal_names_the_chunk_shortly() -> None:
    why = keys.no_principal_why(f"{BASE}/{'p' * 1000}")
    assert "no usable principal" in why and len(why) < 300, why
