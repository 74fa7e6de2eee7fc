"""The router's access control generated from an inventory (pure: no router)."""

from __future__ import annotations

from pathlib import Path

from fleet.inventory import Inventory, parse_inventory
from fleet.security.acl import access_control, payload_limits

INVENTORY = """
[fleet]
name = "lab"
[zenoh]
endpoints = ["tls/10.0.0.5:7447"]
[security]
mode = "mtls"
[defaults]
simulated = true
[arms.a1]
suffix = "_1"
[arms.a2]
suffix = "_2"
agent = "agent-cell2"
[arms.a3]
suffix = "_3"
agent = "agent-cell2"
simulated = false
[principals]
ann = "operator"
kiosk = "observer"
"""


def _inventory(tmp_path: Path) -> Inventory:
    return parse_inventory(INVENTORY, str(tmp_path / "inventory.toml"))


def _allowed(acl: dict, principal: str, message: str, flow: str) -> set[str]:  # type: ignore[type-arg]
    policy = next(p for p in acl["policies"] if p["subjects"] == [principal])
    rules = {r["id"]: r for r in acl["rules"]}
    return {
        key
        for rule_id in policy["rules"]
        for key in rules[rule_id]["key_exprs"]
        if message in rules[rule_id]["messages"] and flow in rules[rule_id]["flows"]
    }


def test_deny_by_default_and_every_principal_is_a_subject(tmp_path: Path) -> None:
    acl = access_control(_inventory(tmp_path))
    assert acl["enabled"] and acl["default_permission"] == "deny"
    names = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert names["ann"] == ["ann"] and names["agent-cell2"] == ["agent-cell2"]
    assert {"coordinator", "viewer", "kiosk", "agent-a1", "router"} <= set(names)


def test_an_agent_publishes_and_serves_only_its_own_arms(tmp_path: Path) -> None:
    acl = access_control(_inventory(tmp_path))
    puts = _allowed(acl, "agent-cell2", "put", "ingress")
    assert "fleet/lab/arm/a2/joints" in puts and "fleet/lab/arm/a3/contact" in puts
    assert not any("/a1/" in key for key in puts)
    served = _allowed(acl, "agent-cell2", "declare_queryable", "ingress")
    assert served == {"fleet/lab/arm/a2/cmd/*", "fleet/lab/arm/a3/cmd/*", "fleet/lab/info/*/*"}


def test_identity_keys_belong_to_their_principal(tmp_path: Path) -> None:
    acl = access_control(_inventory(tmp_path))
    assert "fleet/lab/heartbeat/ann" in _allowed(acl, "ann", "put", "ingress")
    assert "fleet/lab/heartbeat/coordinator" not in _allowed(acl, "ann", "put", "ingress")
    assert _allowed(acl, "ann", "query", "ingress") == {
        "fleet/lab/arm/*/cmd/ann",
        "fleet/lab/coordinator/cmd/ann",
        "fleet/lab/info/*/*",
    }


def test_fleet_doctor_may_ask_every_process_who_it_is(tmp_path: Path) -> None:
    """Under mTLS info/** was answered to nobody, then by the router alone (a query must lie
    within what the queryables may serve): the querier asks info/*/*, as they serve."""
    acl = access_control(_inventory(tmp_path))
    for person in ("ann", "viewer"):  # an operator, an observer: who runs fleet doctor
        assert "fleet/lab/info/*/*" in _allowed(acl, person, "query", "ingress")
        assert "fleet/lab/info/*/*" in _allowed(acl, person, "reply", "egress")
    for process in ("agent-cell2", "coordinator", "viewer"):
        assert "fleet/lab/info/*/*" in _allowed(acl, process, "declare_queryable", "ingress")
        assert "fleet/lab/info/*/*" in _allowed(acl, process, "query", "egress")


def test_observers_stop_but_never_reset_or_command(tmp_path: Path) -> None:
    acl = access_control(_inventory(tmp_path))
    for observer in ("viewer", "kiosk"):
        puts = _allowed(acl, observer, "put", "ingress")
        stops = {"fleet/lab/estop", "fleet/lab/arm/*/estop"}
        # and the same stops' datagram copies (their keys under fleet/lab/dg), nothing else
        assert puts == stops | {"fleet/lab/dg/estop", "fleet/lab/dg/arm/*/estop"}
        # no command query: only "who are you" (fleet doctor, issue 28)
        assert _allowed(acl, observer, "query", "ingress") == {"fleet/lab/info/*/*"}


def test_only_maintainers_inject_faults_into_simulated_arms(tmp_path: Path) -> None:
    acl = access_control(_inventory(tmp_path))
    assert "fleet/lab/arm/*/sim/fault" in _allowed(acl, "maintainer", "query", "ingress")
    assert "fleet/lab/arm/*/sim/fault" not in _allowed(acl, "ann", "query", "ingress")
    served = _allowed(acl, "sim", "declare_queryable", "ingress")
    assert served - {"fleet/lab/info/*/*"} == {
        "fleet/lab/arm/a1/sim/fault",
        "fleet/lab/arm/a2/sim/fault",
    }  # a3: real


def test_payload_limits(tmp_path: Path) -> None:
    small, beats, everything = payload_limits(_inventory(tmp_path))
    assert small["size_limit"] == 4096 and "fleet/lab/estop" in small["key_exprs"]
    assert beats["key_exprs"] == ["fleet/lab/heartbeat/*", "fleet/lab/dg/heartbeat/*"]
    assert beats["size_limit"] < 64 * 1024
    assert "fleet/lab/dg/arm/*/estop" in small["key_exprs"]
    assert everything["size_limit"] == 1 << 20 and everything["key_exprs"] == ["**"]


def test_security_needs_tls_endpoints_and_known_roles(tmp_path: Path) -> None:
    import pytest

    from fleet.inventory import InventoryError
    from fleet.security.session import credentials

    plain = parse_inventory(INVENTORY.replace("tls/10.0.0.5", "tcp/10.0.0.5"), str(tmp_path / "i"))
    with pytest.raises(InventoryError, match="tls/ endpoints"):
        credentials(plain, "operator")
    with pytest.raises(InventoryError, match="role 'admin'"):
        parse_inventory(INVENTORY + 'root = "admin"\n', str(tmp_path / "inventory.toml"))
    with pytest.raises(InventoryError, match="an arm's agent"):
        parse_inventory(INVENTORY + 'agent-a1 = "operator"\n', str(tmp_path / "inventory.toml"))


DEVICES = """
[grippers.gl]
mount = "a1"
[grippers.gr]
agent = "agent-cell2"
side = "right"
[g1.h1]
"""


def test_device_agents_publish_their_devices_and_only_commanders_command(tmp_path: Path) -> None:
    """Issue 14: device keys are covered like the arms' (deny by default)."""
    inventory = parse_inventory(INVENTORY + DEVICES, str(tmp_path / "inventory.toml"))
    acl = access_control(inventory)
    # A gripper mounted on a1 is served by a1's agent (one process, one identity, by default).
    puts = _allowed(acl, "agent-a1", "put", "ingress")
    assert "fleet/lab/gripper/gl/state" in puts and "fleet/lab/gripper/gl/estop/ack" in puts
    assert "fleet/lab/arm/a1/joints" in puts
    assert not any("/gr/" in key or "/h1/" in key or "/a2/" in key for key in puts)
    assert "fleet/lab/gripper/gl/cmd/*" in _allowed(acl, "agent-a1", "declare_queryable", "ingress")
    cell2 = _allowed(acl, "agent-cell2", "put", "ingress")
    assert "fleet/lab/gripper/gr/state" in cell2 and "fleet/lab/arm/a2/joints" in cell2
    assert "fleet/lab/g1/h1/state" in _allowed(acl, "agent-h1", "put", "ingress")
    # Commands: an operator under its own name only; an observer may stop, never command.
    assert "fleet/lab/g1/*/cmd/ann" in _allowed(acl, "ann", "query", "ingress")
    assert "fleet/lab/gripper/*/cmd/kiosk" not in _allowed(acl, "kiosk", "query", "ingress")
    assert "fleet/lab/g1/*/estop" in _allowed(acl, "kiosk", "put", "ingress")
    assert "fleet/lab/g1/*/reset" not in _allowed(acl, "kiosk", "put", "ingress")
    assert not any("/gripper/" in k for k in _allowed(acl, "agent-h1", "put", "ingress"))
    coordinator = _allowed(acl, "coordinator", "declare_subscriber", "ingress")
    assert {"fleet/lab/gripper/*/state", "fleet/lab/g1/*/estop/ack"} <= coordinator
    # The router's 4 KiB limit covers the devices' commands, stops and resets (issue 21).
    small = next(f for f in payload_limits(inventory) if f["id"] == "commands")["key_exprs"]
    for kind in ("gripper", "g1"):
        assert {f"fleet/lab/{kind}/*/{k}" for k in ("cmd/**", "estop", "reset")} <= set(small)


MIXED = (
    INVENTORY.split("[arms.a2]")[0]  # the fleet, its security and a1
    + """[grippers.gl]
mount = "a1"
[g1.h1]
interface = ""
[principals]
ann = "operator"
"""
)


def test_every_key_each_kind_uses_is_granted_to_who_uses_it(tmp_path: Path) -> None:
    """The agent publishes every channel of its kinds (a G1's lowstate was denied: the secure
    demo's G1 was never posed), commanders command, readers read: no gap."""
    from fleet.security.coverage import gaps

    inventory = parse_inventory(MIXED, str(tmp_path / "inventory.toml"))
    assert set(inventory.devices) == {"gl", "h1"}
    assert gaps(inventory) == []
    agent = inventory.device("h1").agent
    puts = _allowed(access_control(inventory), agent, "put", "ingress")
    assert "fleet/lab/g1/h1/lowstate" in puts


def test_a_channel_the_rules_forget_is_named(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """What fleet doctor says when the rules leave a channel out."""
    from fleet.security import acl, coverage

    inventory = parse_inventory(MIXED, str(tmp_path / "inventory.toml"))
    forgetful = lambda kind: [c for c in acl.device_payloads(kind) if c == "state"]  # noqa: E731
    monkeypatch.setattr(acl, "device_agent_channels", forgetful)
    found = {str(gap) for gap in coverage.gaps(inventory)}
    assert any(g.endswith("may not put fleet/lab/g1/h1/lowstate") for g in found), found


def test_fleet_doctor_fails_when_a_unit_key_is_denied(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``fleet doctor`` said OK while the router denied the G1's lowstate: it checks now."""
    from fleet import doctor
    from fleet.security import acl

    inventory = parse_inventory(MIXED, str(tmp_path / "inventory.toml"))
    [ok] = doctor.check_access_rules(inventory)
    assert ok.level == "ok", ok
    forgetful = lambda kind: [c for c in acl.device_payloads(kind) if c == "state"]  # noqa: E731
    monkeypatch.setattr(acl, "device_agent_channels", forgetful)
    [failed] = doctor.check_access_rules(inventory)
    assert failed.level == "fail" and "fleet/lab/g1/h1/lowstate" in failed.detail, failed
    plain = parse_inventory(MIXED.replace('mode = "mtls"', 'mode = "none"'), str(tmp_path / "i"))
    assert doctor.check_access_rules(plain) == []


def test_a_players_choreography_state_is_put_under_its_own_name(tmp_path: Path) -> None:
    acl = access_control(_inventory(tmp_path))
    puts = _allowed(acl, "ann", "put", "ingress")
    assert "fleet/lab/choreo/ann" in puts and "fleet/lab/choreo/operator" not in puts
    assert not any("/choreo/" in key for key in _allowed(acl, "kiosk", "put", "ingress"))
