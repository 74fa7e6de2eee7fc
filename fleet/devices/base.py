"""What every device kind beside the D1 arm shares: its network fields and safety timings.

A device's inventory table (``[grippers.<id>]``, ``[g1.<id>]``) is a Struct deriving from
``DeviceBase``; ``[defaults]`` gives it the network fields it sets (interface, peers, multicast,
domain_id, simulated, agent), never the arm-only ones. The device command envelope and reply
live in the key space's messages (``fleet.wire.messages``), re-exported here.
"""

from __future__ import annotations

from msgspec import Struct

from fleet.wire.messages import DeviceCommand, DeviceReply
from fleet.wire.messages import DeviceRelease as Release

__all__ = ["NETWORK_FIELDS", "DeviceBase", "DeviceCommand", "DeviceReply", "Release"]

NETWORK_FIELDS = ("interface", "peers", "multicast", "domain_id", "simulated")
"""Fields of ``[defaults]`` that devices inherit too (the rest of it is the arms')."""


class DeviceBase(Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """Fields of every device: who serves it and on which DDS network."""

    id: str = ""
    agent: str = ""
    """The principal of the edge agent serving this device (default: the agent of the arm it is
    mounted on, so one process serves both; else ``agent-<id>``)."""
    interface: str = "lo"
    peers: list[str] | None = None
    multicast: bool = False
    domain_id: int | None = None
    simulated: bool = False
    link_stale_s: float = 0.35
    """No state sample for this long: the link is ``stale`` (commands are refused)."""
    watchdog_s: float = 0.5
    """A device moving under a coordinator's command is stopped when that coordinator's
    heartbeat is silent this long (as an arm is)."""
    lease_s: float = 3.0
    """An owner's lease on the device lasts this long after its last command."""
