"""What every device kind beside the D1 arm shares: its network fields and its replies.

A device's inventory table (``[grippers.<id>]``, ``[g1.<id>]``) is a Struct deriving from
``DeviceBase``; ``[defaults]`` gives it the network fields it sets (interface, peers, multicast,
domain_id, simulated, agent), never the arm-only ones.
"""

from __future__ import annotations

from typing import Annotated

from msgspec import Meta, Struct

from fleet.wire.messages import ErrorInfo, Lifetime, Name, StampNs

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


class DeviceReply(Struct, frozen=True):
    """The reply to a device command (``<kind>/<device>/cmd/<principal>``): ``ok``, the device,
    what was written (``written``: a short text of the DDS message) and the error, if any, with
    the arm's error codes (``fleet.wire.messages.ErrorCode``)."""

    ok: bool
    device: Annotated[str, Meta(max_length=128)]
    error: ErrorInfo | None = None
    written_ns: Annotated[int, Meta(ge=0, le=2**63 - 1)] | None = None
    result: Annotated[str, Meta(max_length=1024)] | None = None
    """A query's answer (``get_fsm_id``: the id), as text."""


class DeviceCommand(Struct, tag_field="op", kw_only=True, forbid_unknown_fields=True):
    """The envelope every device command carries, as the arm's do: ``owner`` (a lease: others
    are refused 3207 until it expires) and ``takeover``; ``stamp_ns`` (the sender's clock,
    increasing per client: duplicates and out-of-order commands are refused) and
    ``lifetime_s`` (a command arriving later than that is refused, never executed)."""

    owner: Name | None = None
    takeover: bool = False
    stamp_ns: StampNs | None = None
    lifetime_s: Lifetime | None = None


class Release(DeviceCommand, tag="release", kw_only=True):
    """Give the device up (ends ``owner``'s lease and its watchdog watch); nothing is written."""
