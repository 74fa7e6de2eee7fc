"""inventory.toml -> Inventory: the repo's file parses; every error names the file and the path."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleet.inventory import DEFAULT_ENDPOINT, InventoryError, load_inventory, parse_inventory

REPO_INVENTORY = Path(__file__).resolve().parents[2] / "inventory.toml"
FILE = "fleet-x.toml"
BASE = '[fleet]\nname = "lab"\n'


def _error(text: str) -> str:
    with pytest.raises(InventoryError) as info:
        parse_inventory(text, FILE)
    message = str(info.value)
    assert message.startswith(f"{FILE}: "), message
    return message


def test_repo_inventory_parses() -> None:
    inventory = load_inventory(REPO_INVENTORY)
    assert inventory.path == str(REPO_INVENTORY)
    assert inventory.fleet == "lab"
    assert inventory.endpoints == ["tcp/127.0.0.1:7447"]
    assert inventory.domain_id == 0
    assert inventory.peers == ["127.0.0.1"]
    assert list(inventory.arms) == ["a1", "a2", "a3"]
    assert [a.suffix for a in inventory.arms.values()] == ["_1", "_2", "_3"]
    for arm_id, arm in inventory.arms.items():
        assert arm.id == arm_id
        assert arm.interface == "lo"
        assert arm.simulated is True
        assert arm.stop_action == "hold"
        assert inventory.domain_of(arm) == 0
        assert inventory.peers_of(arm) == ("127.0.0.1",)
    assert inventory.arms["a1"].base_xyz == (0.0, -0.6, 0.0)
    assert inventory.groups == {"left": ["a1", "a2"]}
    assert inventory.resolve("left") == ["a1", "a2"]
    assert inventory.resolve("all") == ["a1", "a2", "a3"]
    assert inventory.resolve("a3") == ["a3"]


def test_minimal_inventory_gets_the_defaults() -> None:
    inventory = parse_inventory(BASE + "[arms.a1]\n", FILE)
    assert inventory.endpoints == [DEFAULT_ENDPOINT]
    assert inventory.domain_id == 0
    arm = inventory.arm("a1")
    assert arm.suffix == ""
    assert arm.interface == "lo"
    assert arm.stop_action == "hold"
    assert arm.joint_sign == (1,) * 7
    assert 0 < arm.link_stale_s < arm.link_lost_s
    assert inventory.groups == {}


def test_defaults_apply_and_arms_override() -> None:
    text = BASE + (
        '[dds]\ndomain_id = 5\npeers = ["10.0.0.1"]\n'
        '[defaults]\ninterface = "eth1"\nstop_action = "unload"\nlink_stale_s = 0.5\n'
        'peers = ["192.168.123.100"]\n'
        '[arms.a1]\nsuffix = "_1"\n'
        '[arms.a2]\nsuffix = "_2"\nstop_action = "power_off"\ninterface = "eth2"\n'
        "domain_id = 7\npeers = []\n"
    )
    inventory = parse_inventory(text, FILE)
    a1, a2 = inventory.arm("a1"), inventory.arm("a2")
    assert (a1.interface, a1.stop_action, a1.link_stale_s) == ("eth1", "unload", 0.5)
    assert (a2.interface, a2.stop_action, a2.link_stale_s) == ("eth2", "power_off", 0.5)
    assert inventory.domain_of(a1) == 5 and inventory.domain_of(a2) == 7
    assert inventory.peers_of(a1) == ("192.168.123.100",)
    assert inventory.peers_of(a2) == ()


def test_with_domain_and_endpoints_make_copies() -> None:
    inventory = parse_inventory(BASE + "[arms.a1]\ndomain_id = 3\n", FILE)
    moved = inventory.with_domain(42).with_endpoints(["tcp/127.0.0.1:9999"])
    assert moved.domain_of(moved.arm("a1")) == 42
    assert moved.endpoints == ["tcp/127.0.0.1:9999"]
    assert inventory.domain_of(inventory.arm("a1")) == 3  # the original is unchanged


def test_same_suffix_on_other_interface_or_domain_is_fine() -> None:
    text = BASE + (
        '[arms.a1]\nsuffix = "_1"\ninterface = "eth0"\n'
        '[arms.a2]\nsuffix = "_1"\ninterface = "eth1"\n'
        '[arms.a3]\nsuffix = "_1"\ninterface = "eth0"\ndomain_id = 9\n'
    )
    assert list(parse_inventory(text, FILE).arms) == ["a1", "a2", "a3"]


def test_unknown_arm_is_named_with_the_known_ones() -> None:
    inventory = load_inventory(REPO_INVENTORY)
    with pytest.raises(InventoryError, match=r"no arm 'a9' \(known arms: a1, a2, a3\)"):
        inventory.arm("a9")
    with pytest.raises(InventoryError):
        inventory.resolve("nobody")


def test_missing_file_names_the_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(InventoryError, match="nope.toml: cannot read the inventory"):
        load_inventory(missing)


def test_load_names_the_file_in_errors(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(BASE + '[arms.a1]\nsufix = "_1"\n', encoding="utf-8")
    with pytest.raises(InventoryError) as info:
        load_inventory(path)
    assert str(info.value).startswith(f"{path}: arms.a1: ")
    assert "sufix" in str(info.value)


# (text, fragments every one of which the message must contain)
ERRORS = [
    pytest.param(BASE + '[arms.a1]\nsufix = "_1"\n', ["arms.a1", "sufix"], id="misspelled-field"),
    pytest.param(
        BASE + '[defaults]\nintreface = "lo"\n[arms.a1]\n',
        ["defaults", "intreface"],
        id="misspelled-default",
    ),
    pytest.param(
        '[fleet]\nname = "lab"\nnaem = "x"\n[arms.a1]\n', ["fleet", "naem"], id="fleet-field"
    ),
    pytest.param(BASE + "[arm.a1]\n", ["unknown section [arm]"], id="unknown-section"),
    pytest.param(BASE + "[arms.a1]\nsuffix = 1\n", ["$.arms.a1.suffix", "str"], id="wrong-type"),
    pytest.param(
        BASE + '[arms.a1]\nlink_stale_s = "fast"\n',
        ["$.arms.a1.link_stale_s", "float"],
        id="wrong-type-float",
    ),
    pytest.param(
        BASE + '[zenoh]\nendpoints = "tcp/127.0.0.1:7447"\n[arms.a1]\n',
        ["$.zenoh.endpoints"],
        id="wrong-type-endpoints",
    ),
    pytest.param(
        BASE + "[arms.a1]\nbase_xyz = [1.0, 2.0]\n",
        ["$.arms.a1.base_xyz"],
        id="wrong-length",
    ),
    pytest.param(
        BASE + '[arms.a1]\nsuffix = "_1"\n[arms.a2]\nsuffix = "_1"\n',
        ["arms.a2", "'_1'", "'lo'", "already used by arm 'a1'"],
        id="duplicate-suffix",
    ),
    pytest.param(
        BASE + "[arms.a1]\n[arms.a2]\n",
        ["arms.a2", "suffix ''", "already used by arm 'a1'"],
        id="duplicate-empty-suffix",
    ),
    pytest.param(
        BASE + '[arms.a1]\n[groups]\nleft = ["a1", "a9"]\n',
        ["groups.left", "unknown arm 'a9'"],
        id="unknown-group-member",
    ),
    pytest.param(
        BASE + '[arms.a1]\n[groups]\na1 = ["a1"]\n', ["groups.a1", "taken"], id="group-is-arm"
    ),
    pytest.param(
        BASE + '[arms.a1]\n[groups]\nall = ["a1"]\n', ["groups.all", "taken"], id="group-all"
    ),
    pytest.param('[arms.a1]\nsuffix = "_1"\n', ["missing [fleet]"], id="missing-fleet"),
    pytest.param("", ["missing [fleet]"], id="empty-file"),
    pytest.param(BASE, ["no arms"], id="no-arms"),
    pytest.param(
        BASE + '[arms.a1]\nstop_action = "brake"\n',
        ["$.arms.a1.stop_action", "brake"],
        id="bad-stop-action",
    ),
    pytest.param(
        BASE + '[defaults]\nstop_action = "brake"\n[arms.a1]\n',
        ["$.defaults.stop_action", "brake"],
        id="bad-default-stop-action",
    ),
    pytest.param(
        BASE + "[arms.a1]\njoint_sign = [1, 1, 1, 1, 1, 1, 2]\n",
        ["arms.a1", "joint_sign"],
        id="bad-joint-sign-value",
    ),
    pytest.param(
        BASE + "[arms.a1]\njoint_sign = [1, -1]\n", ["arms.a1", "joint_sign"], id="short-joint-sign"
    ),
    pytest.param(
        BASE + "[arms.a1]\njoint_sign = [1, 1, 1, 1, 1, 1, 0]\n",
        ["arms.a1", "joint_sign"],
        id="zero-joint-sign",
    ),
    pytest.param(
        BASE + '[arms.a1]\nsuffix = "_a b"\n', ["arms.a1", "suffix '_a b'"], id="bad-suffix"
    ),
    pytest.param(
        BASE + '[arms.a1]\nsuffix = "_1\\n"\n', ["arms.a1", "suffix"], id="suffix-newline"
    ),
    pytest.param(BASE + '[arms."a/1"]\n', ["arms.a/1", "not usable in a key"], id="bad-arm-name"),
    pytest.param(
        '[fleet]\nname = "l ab"\n[arms.a1]\n', ["fleet.name", "not usable"], id="bad-fleet-name"
    ),
    pytest.param(
        '[fleet]\nname = "lab\\n"\n[arms.a1]\n', ["fleet.name", "not usable"], id="fleet-newline"
    ),
    pytest.param(
        BASE + "[arms.a1]\nlink_stale_s = 3.0\n", ["arms.a1", "link_stale_s"], id="stale-after-lost"
    ),
    pytest.param(
        BASE + "[arms.a1]\nrecv_ack_timeout_s = 0\n", ["arms.a1", "timeouts"], id="zero-timeout"
    ),
    pytest.param(
        BASE + "[dds]\ndomain_id = 300\n[arms.a1]\n", ["dds.domain_id", "300"], id="domain"
    ),
    pytest.param(
        BASE + "[arms.a1]\ndomain_id = 233\n", ["arms.a1", "domain_id 233"], id="arm-domain"
    ),
    pytest.param(BASE + '[arms.a1]\nid = "x"\n', ["arms.a1", "remove 'id'"], id="id-in-arm"),
    pytest.param(
        BASE + '[defaults]\nid = "x"\n[arms.a1]\n', ["defaults", "'id'"], id="id-in-defaults"
    ),
    pytest.param(BASE + "[arms]\na1 = 3\n", ["arms.a1", "table"], id="arm-not-table"),
    pytest.param('defaults = 3\n[fleet]\nname = "lab"\n[arms.a1]\n', ["defaults"], id="defaults-3"),
    pytest.param('groups = 3\n[fleet]\nname = "lab"\n[arms.a1]\n', ["groups"], id="groups-3"),
    pytest.param('fleet = "lab"\n[arms.a1]\n', ["fleet"], id="fleet-not-table"),
    pytest.param(BASE + "[arms.a1\n", ["not valid TOML"], id="bad-toml"),
]


@pytest.mark.parametrize(("text", "fragments"), ERRORS)
def test_errors_name_the_file_and_the_path(text: str, fragments: list[str]) -> None:
    message = _error(text)
    for fragment in fragments:
        assert fragment in message, message


@pytest.mark.parametrize(
    "arm_line",
    ["watchdog_s = nan", "lease_s = inf", "link_stale_s = -inf", "base_xyz = [0.0, nan, 0.0]"],
)
def test_non_finite_numbers_are_refused_with_their_path(arm_line: str) -> None:
    text = f'[fleet]\nname = "x"\n[arms.a1]\n{arm_line}\n'
    with pytest.raises(InventoryError, match=r"inventory.toml: arms\.a1: .*not a finite number"):
        parse_inventory(text)


def test_non_finite_coordinator_rate_is_refused() -> None:
    text = '[fleet]\nname = "x"\n[coordinator]\nheartbeat_hz = inf\n[arms.a1]\n'
    with pytest.raises(InventoryError, match="coordinator: heartbeat_hz"):
        parse_inventory(text)


@pytest.mark.parametrize(
    ("line", "fragment"),
    [
        ('[arms.a1]\ninterface = "lola\\f"', "arms.a1: interface 'lola\\x0c' must be"),
        ('[defaults]\npeers = ["10.0.0.1", "\\u0001"]\n[arms.a1]', "arms.a1: peer '\\x01'"),
        ('[dds]\npeers = ["\\b"]\n[arms.a1]', "dds.peers: peer '\\x08' must be"),
        # A device's network is checked as an arm's (a control character aborted its agent).
        ('[arms.a1]\n[grippers.gl]\ninterface = "e\\u0001"', "grippers.gl: interface 'e\\x01'"),
        ('[arms.a1]\n[g1.h1]\npeers = ["\\f"]', "g1.h1: peer '\\x0c' must be"),
    ],
)
def test_interface_and_peers_must_be_printable(line: str, fragment: str) -> None:
    """Found by `make fuzz` (fuzz/inventory.py): a control character in an interface name or a
    peer made malformed CycloneDDS XML, and the agent failed at start with "Non specific
    error" instead of an error naming the file and the path."""
    with pytest.raises(InventoryError) as info:
        parse_inventory(f'[fleet]\nname = "x"\n{line}\n')
    assert fragment in str(info.value), info.value


def test_the_simulated_g1s_lowstate_rate_stays_fresh_for_the_agent() -> None:
    """``sim_lowstate_hz`` (a test bed's slower rt/lowstate) must keep a sample within the
    agent's ``link_stale_s`` and not exceed the state rate."""
    head = '[fleet]\nname = "x"\n[arms.a1]\n[g1.h1]\n'
    assert parse_inventory(head + "sim_lowstate_hz = 10.0\n").devices["h1"].sim_lowstate_hz == 10
    for rate in ("2.0", "200.0"):
        with pytest.raises(InventoryError, match="g1.h1.*sim_lowstate_hz must"):
            parse_inventory(head + f"sim_lowstate_hz = {rate}\n")
