"""The router's access control for ROS 2 (issue 27): exactly the ROS keys ``fleet ros2`` needs,
its readers' keys, and the Trigger stops only for ``[ros2] estop_callers``. Pure."""

from __future__ import annotations

from pathlib import Path

from fleet.inventory import parse_inventory
from fleet.ros2 import grants
from fleet.security.acl import access_control
from tests.unit.test_acl import INVENTORY, _allowed

ROS2 = '\n[ros2]\nestop_callers = ["ann"]\n[ros2.namespaces]\na1 = "/lab/left"\n'
JS = "sensor_msgs::msg::dds_::JointState_/RIHS01_"


def test_ros2_principal_puts_exactly_its_topics(tmp_path: Path) -> None:
    inventory = parse_inventory(INVENTORY + ROS2, str(tmp_path / "inventory.toml"))
    acl = access_control(inventory)
    puts = _allowed(acl, "ros2", "put", "ingress")
    ros = {k for k in puts if not k.startswith("fleet/")}
    assert ros == {*grants.data_keys(inventory), *grants.cache_keys(inventory)}
    assert any(k.startswith(f"0/lab/left/joint_states/{JS}") for k in ros)  # namespace given
    assert any(k.startswith(f"0/lab/a2/joint_states/{JS}") for k in ros)  # default namespace
    assert all("*" not in k.split("@adv")[0] for k in ros)  # concrete keys, no wildcard
    served = _allowed(acl, "ros2", "declare_queryable", "ingress")
    assert {k for k in served if "Trigger_" in k} == set(grants.service_keys(inventory))
    assert "@ros2_lv/0/**" in _allowed(acl, "ros2", "liveliness_token", "ingress")
    assert "fleet/lab/estop" in puts  # it issues the fleet's stop


def test_only_named_callers_may_stop_through_ros(tmp_path: Path) -> None:
    inventory = parse_inventory(INVENTORY + ROS2, str(tmp_path / "inventory.toml"))
    acl = access_control(inventory)
    trigger = set(grants.service_keys(inventory))
    assert trigger <= _allowed(acl, "ann", "query", "ingress")
    for other in ("viewer", "maintainer", "coordinator"):
        assert not trigger & _allowed(acl, other, "query", "ingress"), other
    # readers see the graph and the topics, and get the caches (late joiners)
    assert "@ros2_lv/0/**" in _allowed(acl, "viewer", "declare_liveliness_subscriber", "ingress")
    assert set(grants.cache_keys(inventory)) <= _allowed(acl, "viewer", "query", "ingress")
    assert set(grants.data_keys(inventory)) <= _allowed(
        acl, "viewer", "declare_subscriber", "ingress"
    )


def test_no_ros_keys_for_readers_without_a_ros2_section(tmp_path: Path) -> None:
    acl = access_control(parse_inventory(INVENTORY, str(tmp_path / "inventory.toml")))
    for reader in ("ann", "viewer"):
        keys = _allowed(acl, reader, "declare_subscriber", "ingress")
        assert all(k.startswith("fleet/") for k in keys), keys


def test_devices_joint_states_and_humbles_keys_are_granted(tmp_path: Path) -> None:
    devices = '\n[grippers.gl]\nmount = "a1"\n\n[g1.h1]\n'
    inventory = parse_inventory(INVENTORY + ROS2 + devices, str(tmp_path / "inventory.toml"))
    names = {fqn for fqn, _t, _l in grants.topics(inventory)}
    assert {"/lab/gl/joint_states", "/lab/h1/joint_states"} <= names
    humble = parse_inventory(
        INVENTORY + ROS2.replace("[ros2.namespaces]", 'distro = "humble"\n[ros2.namespaces]'),
        str(tmp_path / "inventory.toml"),
    )
    keys = [*grants.data_keys(humble), *grants.service_keys(humble)]
    assert keys and all(k.endswith("/TypeHashNotSupported") for k in keys)
    puts = _allowed(access_control(humble), "ros2", "put", "ingress")
    assert (
        "0/lab/left/joint_states/sensor_msgs::msg::dds_::JointState_/TypeHashNotSupported" in puts
    )
