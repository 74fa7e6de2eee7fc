"""Issue 24's configuration, pure: the datagram twin of each endpoint, the inventory's
``[zenoh] datagram`` and ``stop_dscp``, QUIC datagrams in secure modes, the routers' QoS
overwrite of the stop keys."""

from __future__ import annotations

import json

import pytest

from fleet.inventory import InventoryError, parse_inventory
from fleet.security.session import datagram_session, router_config
from fleet.wire import stoppath
from fleet.wire.keys import KeySpace, datagram_key, is_datagram_key, reliable_key
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
        "fleet/lab/dg/heartbeat/*",  # the datagram copies' (their stops and acks: by ** above)
        "fleet/lab/reset",
        "fleet/lab/**/reset",
    }
    config = router_config(parse_inventory(BASE, "x.toml"), ["tcp/127.0.0.1:7447"])
    assert "d1_fleet_stops" in config.get_json("qos/network")
    # Nothing leaves a router as BLOCK: a frozen subscriber must never hold it up.
    assert "d1_fleet_never_wait_for_a_consumer" in config.get_json("qos/network")
    assert json.loads(config.get_json("listen/endpoints")) == [
        "tcp/127.0.0.1:7447",
        "udp/127.0.0.1:7447",
    ]


def test_a_datagram_copy_has_a_key_of_its_own_that_parses_as_the_key_it_copies() -> None:
    space = KeySpace("lab")
    for key in (space.estop, space.arm("a1", "estop/ack"), space.heartbeat_of("ann")):
        twin = datagram_key(key)
        assert twin.startswith("fleet/lab/dg/") and is_datagram_key(twin)
        assert not is_datagram_key(key) and reliable_key(twin) == key == reliable_key(key)
        assert space.parse_key(twin) == space.parse_key(key)
    assert datagram_key("fleet/lab/**/estop") == "fleet/lab/dg/**/estop"
    assert not is_datagram_key("fleet/dg") and not is_datagram_key("other/lab/dg/estop")


class _Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


def test_copies_that_only_now_became_due_get_the_deaf_wait_from_then(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A session that heard copies long ago (the last watch), then hears a beat over TCP
    that announces copies again (a new watch): deaf only if none comes within ``DEAF_S`` of
    that beat, never at once (the copies come 25 ms after their TCP beat); and deaf, as
    before, when they stop while the reliable path keeps announcing them."""
    clock = _Clock()
    monkeypatch.setattr(stoppath, "time", clock)
    session = stoppath.DatagramSession(None)
    session._heard()  # copies heard during the last watch
    clock.now += 60.0  # an idle minute: beats without copies, none heard_reliably
    assert not session.deaf(clock.now)
    session.heard_reliably()  # the first beat announcing copies again
    assert not session.deaf(clock.now)
    for _ in range(int(stoppath.DEAF_S / 0.1) - 1):
        clock.now += 0.1
        session.heard_reliably()
        assert not session.deaf(clock.now)
    clock.now += 0.2
    session.heard_reliably()
    assert session.deaf(clock.now)  # DEAF_S of announced copies, none heard
    session._heard()
    assert not session.deaf(clock.now)
