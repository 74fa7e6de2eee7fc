"""Issue 24's configuration, pure: the datagram twin of each endpoint, the inventory's
``[zenoh] datagram`` and ``stop_dscp``, QUIC datagrams in secure modes, the routers' QoS
overwrite of the stop keys."""

from __future__ import annotations

import json

import pytest

from fleet.inventory import InventoryError, parse_inventory
from fleet.security.session import datagram_session, router_config
from fleet.wire.keys import KeySpace
from fleet.wire.session import Datagram, datagram_twin, datagram_twins
from fleet.wire.stoppath import stop_qos_overwrite

BASE = '[fleet]\nname = "lab"\n[arms.a1]\n'


def test_each_tcp_endpoint_has_a_udp_twin_each_tls_one_a_quic_twin() -> None:
    assert datagram_twin("tcp/192.168.123.2:7447") == "udp/192.168.123.2:7447"
    assert datagram_twin("tcp/[::1]:7447#iface=eth0") == "udp/[::1]:7447"
    assert datagram_twin("tcp/10.0.0.1:7447", dscp=46) == "udp/10.0.0.1:7447#dscp=184"
    # TLS: QUIC's unreliable datagrams, never plain UDP (it could not be authenticated).
    assert datagram_twin("tls/10.0.0.1:7447") == "quic/10.0.0.1:7447?rel=0"
    assert datagram_twin("tls/10.0.0.1:7447", dscp=46) == "quic/10.0.0.1:7447?rel=0#dscp=184"
    assert datagram_twin("quic/10.0.0.1:7447") is None
    assert datagram_twin("udp/10.0.0.1:7447") is None
    endpoints = ["tcp/a:1", "tls/b:2"]
    assert datagram_twins(endpoints, Datagram()) == ["udp/a:1", "quic/b:2?rel=0"]
    assert datagram_twins(endpoints, Datagram(enabled=False)) == []


def test_the_inventory_switches_the_path_and_marks_it() -> None:
    default = parse_inventory(BASE, "x.toml")
    assert default.datagram == Datagram(enabled=True, dscp=None)
    marked = parse_inventory(BASE + "[zenoh]\nstop_dscp = 46\ndatagram = false\n", "x.toml")
    assert marked.datagram == Datagram(enabled=False, dscp=46)
    with pytest.raises(InventoryError, match="stop_dscp"):
        parse_inventory(BASE + "[zenoh]\nstop_dscp = 64\n", "x.toml")


def test_secure_modes_take_quic_datagrams() -> None:
    text = BASE + '[zenoh]\nendpoints = ["tls/127.0.0.1:7447"]\n[security]\nmode = "mtls"\n'
    inventory = parse_inventory(text, "x.toml")
    assert datagram_session(inventory).path() is None  # not open yet
    assert datagram_session(inventory)._endpoints == "quic/127.0.0.1:7447?rel=0"


def test_routers_pin_the_stop_qos() -> None:
    space = KeySpace("lab")
    (rule,) = stop_qos_overwrite(space)
    assert rule["overwrite"] == {"priority": "real_time", "express": True}
    assert set(rule["key_exprs"]) == {  # type: ignore[arg-type]
        "fleet/lab/estop",
        "fleet/lab/**/estop",
        "fleet/lab/**/estop/ack",
        "fleet/lab/heartbeat/*",
        "fleet/lab/reset",
        "fleet/lab/**/reset",
    }
    config = router_config(parse_inventory(BASE, "x.toml"), ["tcp/127.0.0.1:7447"])
    assert "d1_fleet_stops" in config.get_json("qos/network")
    assert json.loads(config.get_json("listen/endpoints")) == [
        "tcp/127.0.0.1:7447",
        "udp/127.0.0.1:7447",
    ]
