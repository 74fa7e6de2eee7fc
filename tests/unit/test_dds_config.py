"""The shipped loopback CycloneDDS config equals what the agent builds for ("lo", 127.0.0.1)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from fleet.d1.dds import cyclonedds_config

SHIPPED = Path(__file__).resolve().parents[2] / "config" / "cyclonedds-loopback.xml"


def _canonical(text: str) -> str:
    root = ET.fromstring(text)
    for element in root.iter():
        element.text = (element.text or "").strip() or None
        element.tail = None
    return ET.canonicalize(ET.tostring(root, encoding="unicode"), strip_text=True)


def test_shipped_loopback_config_matches_the_builder() -> None:
    assert _canonical(SHIPPED.read_text()) == _canonical(cyclonedds_config("lo", ["127.0.0.1"]))


def test_config_binds_the_interface_with_multicast_off() -> None:
    root = ET.fromstring(cyclonedds_config("eth1", ["192.168.123.100"]))
    assert root.find(".//NetworkInterface").get("name") == "eth1"  # type: ignore[union-attr]
    assert root.findtext(".//AllowMulticast") == "false"
    assert [p.get("address") for p in root.iter("Peer")] == ["192.168.123.100"]
