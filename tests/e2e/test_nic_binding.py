"""NIC binding (the spec's multi-arm method 1) across network namespaces.

Two simulated arms, each alone in its own namespace on its own veth link (192.168.123.0/24 and
192.168.124.0/24, as on a real arm network), both on the default topics ``rt/arm_Command`` and
``rt/arm_Feedback`` (no suffix). One edge agent per host-side interface. Each agent must hear
and command only its own arm, although both arms use the same topics and DDS domain.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from fleet.wire import messages as m
from testkit.harness import FleetHarness, wait_until

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("ip") is None, reason="needs root and iproute2 (ip netns)"
)

NETS = {"left": "192.168.123", "right": "192.168.124"}


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=10)


@pytest.fixture
def two_arm_networks(tmp_path: Path) -> Iterator[dict[str, tuple[str, str]]]:
    """{arm: (namespace, host-side interface)}; torn down whatever happens."""
    tag = f"{os.getpid() % 10000}"
    made: list[str] = []
    try:
        nets = {}
        for arm, net in NETS.items():
            ns, host_if = f"d1t-{arm}-{tag}", f"d1{arm[0]}{tag}"
            _ip("netns", "add", ns)
            made.append(ns)
            _ip("link", "add", host_if, "type", "veth", "peer", "name", "eth0", "netns", ns)
            _ip("addr", "add", f"{net}.1/24", "dev", host_if)
            _ip("link", "set", host_if, "up")
            _ip("-n", ns, "addr", "add", f"{net}.100/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            nets[arm] = (ns, host_if)
        yield nets
    finally:
        for ns in made:  # deleting the namespace deletes its veth pair
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10)


def _arm_table(arm: str, interface: str, peer: str) -> str:
    return (
        f'[arms.{arm}]\nsuffix = ""\ninterface = "{interface}"\npeers = ["{peer}"]\n'
        "simulated = true\n"
    )


def test_each_agent_hears_and_commands_only_the_arm_on_its_card(
    tmp_path: Path, two_arm_networks: dict[str, tuple[str, str]]
) -> None:
    # The fleet's inventory, as the agents' host sees it: one arm behind each card.
    arms = "".join(
        _arm_table(arm, host_if, f"{NETS[arm]}.100")
        for arm, (_ns, host_if) in two_arm_networks.items()
    )
    with FleetHarness(tmp_path, arms=0, extra=arms) as h:
        h.start_router()
        for arm, (ns, _host_if) in two_arm_networks.items():
            # Inside its namespace the arm sees its own eth0 and the host at .1.
            sim_inventory = tmp_path / f"sim-{arm}.toml"
            sim_inventory.write_text(
                f'[fleet]\nname = "test"\n[dds]\ndomain_id = {h.domain}\n'
                + _arm_table(arm, "eth0", f"{NETS[arm]}.1")
            )
            h.start(
                f"sim-{arm}",
                ["-m", "fleet.cli.main", "sim", "--no-zenoh", "--inventory", str(sim_inventory)],
                prefix=("ip", "netns", "exec", ns),
                inventory=False,
            )
        for arm, (_ns, host_if) in two_arm_networks.items():
            h.start(f"agent-{arm}", ["-m", "edge_agent", "--interface", host_if])
        client = h.client()
        wait_until(lambda: h.all_links_ok(client), 30.0)

        target = [20.0, -30.0, 30.0, 0.0, 10.0, 0.0, 0.0]
        reply = client.command("left", m.MoveJoints(angles_deg=target, wait_reached=True))
        assert reply.ok, reply.error
        snapshot = client.snapshot()
        left, right = snapshot["left"][1], snapshot["right"][1]
        assert left is not None and right is not None
        assert max(abs(a - t) for a, t in zip(left.angles_deg, target)) <= 2.0
        assert max(abs(a) for a in right.angles_deg) < 0.5, "the other card's arm moved"
