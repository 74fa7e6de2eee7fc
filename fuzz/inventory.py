"""Fuzz target: the inventory parser (``fleet/inventory.py``, from TOML text).

Property: any text gives an ``Inventory`` or ``InventoryError``, never another exception; an
inventory that parses (arms, devices, or both: a fleet of devices only is valid) answers every
question the processes ask it (each arm and device, its network, each group) without an error,
holds the invariants the parser promises, and gives every arm and device a well-formed
CycloneDDS configuration that names its interface and peers (an agent builds it
before its first DDS participant; malformed XML fails there, far from the file's line).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from fuzz.common import instrumented, main, toml_text

with instrumented():
    from fleet.d1.dds import cyclonedds_config
    from fleet.devices import kind_of
    from fleet.inventory import InventoryError, parse_inventory


def check(data: bytes) -> None:
    """The property, for one input."""
    try:
        inventory = parse_inventory(toml_text(data), "fuzz.toml")
    except InventoryError:
        return
    # an inventory of devices only is valid (issue 14); one with no robot at all is not
    assert inventory.arms or inventory.devices, inventory
    for device_id, device in inventory.devices.items():
        assert inventory.device(device_id) is device and device.id == device_id, device
        kind_of(device)  # every device has a kind the agents can load
        assert inventory.agent_of(device_id), device
        network = inventory.device_network([device_id])
        assert 0 <= network.domain_id <= 232, device
        assert device.link_stale_s > 0 and device.watchdog_s > 0 and device.lease_s > 0, device
        mount = getattr(device, "mount", "")
        assert not mount or mount in inventory.arms, (device, mount)
        _check_dds_config(device.interface, network.peers, device.multicast)
    for arm_id, arm in inventory.arms.items():
        assert inventory.arm(arm_id) is arm
        assert 0 <= inventory.domain_of(arm) <= 232, arm
        inventory.peers_of(arm)
        inventory.network_of([arm_id])
        assert 0 < arm.link_stale_s < arm.link_lost_s, arm
        assert math.isfinite(arm.link_lost_s) and arm.watchdog_s > 0 and arm.lease_s > 0, arm
        assert len(arm.joint_sign) == 7 and set(arm.joint_sign) <= {1, -1}, arm
        _check_dds_config(arm.interface, inventory.peers_of(arm), arm.multicast)
    for group in inventory.groups:
        assert set(inventory.resolve(group)) <= set(inventory.arms), group
    assert inventory.resolve("all") == list(inventory.arms)
    inventory.with_domain(7)


def _check_dds_config(interface: str, peers: tuple[str, ...], multicast: bool) -> None:
    """The arm's CycloneDDS XML parses and says what the inventory says ("" = DDS chooses)."""
    root = ET.fromstring(cyclonedds_config(interface, peers, multicast))  # ParseError: a break
    names = [e.get("name") for e in root.iter("NetworkInterface")]
    assert names == ([interface] if interface else []), (names, interface)
    allow = root.findtext("Domain/General/AllowMulticast")
    assert allow == ("default" if multicast else "false"), (allow, multicast)
    assert [e.get("address") for e in root.iter("Peer")] == list(peers), peers


def seeds() -> list[bytes]:
    """The repository's inventory.toml, the tests' inventory, and one with every arm field."""
    from fuzz.common import REPO
    from testkit.file_tables import inventory_text as bad_files_inventory
    from testkit.harness import inventory_text

    every_field = (
        '[fleet]\nname = "lab"\n[coordinator]\nheartbeat_hz = 10.0\nsync_lead_s = 0.3\n'
        "offline_after_s = 1.0\n"
        '[defaults]\ninterface = "lo"\nsimulated = true\nstop_action = "unload"\n'
        "[defaults.contact]\nenabled = true\nbuffer_size = 64\n"
        "[defaults.contact.arm]\nconfirm_deg = 5.0\n"
        '[arms.a1]\nsuffix = "_1"\npeers = ["127.0.0.1"]\ndomain_id = 3\nbase_xyz = [0.0, 1, 2]\n'
        "base_rpy_deg = [0, 0, 90]\nlink_stale_s = 0.35\nlink_lost_s = 2.0\n"
        "recv_ack_timeout_s = 0.5\nexec_ack_timeout_s = 2.0\nwatchdog_s = 0.5\nlease_s = 3.0\n"
        "joint_sign = [1, -1, 1, -1, 1, 1, 1]\n[arms.a1.contact.gripper]\nforce_limit_deg = 20\n"
        '[arms.a2]\nsuffix = "_2"\n[groups]\nleft = ["a1", "a2"]\n'
    )
    devices = '[grippers.gl]\nmount = "a1"\nagent = "agent-lo"\n\n[g1.h1]\nagent = "agent-lo"\n'
    devices_only = (
        '[fleet]\nname = "lab"\n[defaults]\ninterface = "lo"\nsimulated = true\n'
        '[grippers.gl]\nagent = "agent-lo"\n[g1.h1]\nagent = "agent-lo"\n'
    )
    texts_ = [
        (REPO / "inventory.toml").read_text(encoding="utf-8"),
        inventory_text("test", 7447, 5, arms=1, extra=devices),
        devices_only,
        inventory_text("test", 7447, 5, arms=3),
        bad_files_inventory({}),
        every_field,
    ]
    return [t.encode() for t in texts_]


if __name__ == "__main__":
    main(check)
