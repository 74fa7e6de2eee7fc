"""The ROS keys of an inventory's ``fleet ros2``, for the router's access control. Pure.

``fleet/security/acl.py`` allows exactly these: the ``ros2`` principal puts the data keys,
serves the Trigger keys and the advanced publishers' ``<key>/@adv/**`` (cache queryable,
publisher-detection token, heartbeats), and holds ``@ros2_lv/<domain>/**`` tokens; readers
(operator, maintainer, observer) subscribe to the data keys, query the caches and read the
tokens, and hold tokens of their own (a ROS node announces itself); only ``estop_callers`` may
query the Trigger keys. ``**`` never matches a chunk that starts with ``@`` (Zenoh's
verbatim chunks), hence the explicit ``@adv`` and ``@ros2_lv`` keys.
"""

from __future__ import annotations

from fleet.devices import kind_of
from fleet.inventory import Inventory
from fleet.ros2 import contract as c
from fleet.wire import keys

ADV = "@adv/**"


def fleet_namespace(inventory: Inventory) -> str:
    """``/<fleet>``: the fleet node's namespace (the fleet-wide stop lives there)."""
    return f"/{inventory.fleet.replace('-', '_')}"


def topics(inventory: Inventory) -> list[tuple[str, c.RosType, bool]]:
    """(fully qualified name, type, transient local) of every topic ``fleet ros2`` publishes."""
    section = inventory.ros2
    out = [("/tf", c.TF_MESSAGE, False), ("/tf_static", c.TF_MESSAGE, True)]
    for arm in inventory.arms:
        ns = section.namespace(inventory.fleet, arm)
        out += [
            (f"{ns}/joint_states", c.JOINT_STATE, False),
            (f"{ns}/robot_description", c.STRING, True),
            (f"{ns}/diagnostics", c.DIAGNOSTIC_ARRAY, False),
        ]
    for device_id, device in inventory.devices.items():
        ns = section.namespace(inventory.fleet, device_id)
        if kind_of(device).key in (keys.GRIPPER, keys.G1):
            out.append((f"{ns}/joint_states", c.JOINT_STATE, False))
        out.append((f"{ns}/diagnostics", c.DIAGNOSTIC_ARRAY, False))
    return [(fqn, c.for_distro(rtype, section.distro), latched) for fqn, rtype, latched in out]


def services(inventory: Inventory) -> list[str]:
    """The Trigger stop services: the fleet's, then one per arm and device."""
    section = inventory.ros2
    units = [*inventory.arms, *inventory.devices]
    return [f"{fleet_namespace(inventory)}/estop"] + [
        f"{section.namespace(inventory.fleet, u)}/estop" for u in units
    ]


def data_keys(inventory: Inventory) -> list[str]:
    """Every data key ``fleet ros2`` puts."""
    d = inventory.ros2.domain_id
    return [c.topic_key(d, fqn, rtype) for fqn, rtype, _latched in topics(inventory)]


def cache_keys(inventory: Inventory) -> list[str]:
    """The advanced publishers' keys (``<data key>/@adv/**``) of the transient-local topics."""
    d = inventory.ros2.domain_id
    return [f"{c.topic_key(d, f, t)}/{ADV}" for f, t, latched in topics(inventory) if latched]


def service_keys(inventory: Inventory) -> list[str]:
    """The Trigger services' queryable keys."""
    section = inventory.ros2
    trigger = c.for_distro(c.TRIGGER, section.distro)
    return [c.topic_key(section.domain_id, s, trigger) for s in services(inventory)]


def graph_keys(inventory: Inventory) -> list[str]:
    """The ROS graph's liveliness tokens of this domain."""
    return [f"{c.ADMIN_SPACE}/{inventory.ros2.domain_id}/**"]
