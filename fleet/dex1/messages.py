"""The gripper's key-space payloads (``fleet/<fleet>/gripper/<id>/...``), msgspec Structs.

``fleet schema`` prints them with the others (through the device registry).
"""

from __future__ import annotations

from typing import Annotated, Literal

from msgspec import Meta, Struct

from fleet.wire.messages import Count, DeviceCommand, Name, StampNs, Text
from fleet.wire.messages import DeviceRelease as Release

Radians = Annotated[float, Meta(ge=-100.0, le=100.0)]
Gain = Annotated[float, Meta(ge=0.0, le=10000.0)]
Percent = Annotated[float, Meta(ge=0.0, le=100.0)]


class GripperState(Struct, frozen=True):
    """``gripper/<id>/state``: the newest DDS state sample at the relay rate (latest wins).

    ``q_rad`` 0 = closed, 2*pi = open; ``opening_pct`` by seed 003's mapping. ``dds_samples``
    counts every state sample the agent took, ``relayed`` the ones put here; ``dds_rate_hz``
    is the measured DDS rate. ``link``: ``ok``/``stale`` (no sample for ``link_stale_s``).
    """

    stamp_ns: StampNs
    q_rad: float
    opening_pct: float
    dq_rad_s: float
    tau_est: float
    temperature_c: float
    error: int
    lost: int
    link: Literal["ok", "stale"]
    target_rad: float | None
    gripping: bool
    estopped: bool
    stop_reason: Text | None
    dds_samples: Count
    relayed: Count
    bad_samples: Count
    dds_rate_hz: float
    family: Literal["hg", "go"]
    mount: Name | Literal[""]
    watched_by: Text | None = None
    """The commander whose heartbeat the gripper's watchdog watches now (None: none)."""


class _GripperCommand(DeviceCommand, kw_only=True):
    pass


class GripperMove(_GripperCommand, tag="move", kw_only=True):
    """Move to ``open_pct`` (0 closed .. 100 open) or ``q_rad`` (exactly one of them); effort
    ``tau``, gains ``kp``/``kd`` (the inventory's defaults when omitted; limits from it too)."""

    open_pct: Percent | None = None
    q_rad: Radians | None = None
    tau: Gain | None = None
    kp: Gain | None = None
    kd: Gain | None = None


class GripperHold(_GripperCommand, tag="hold", kw_only=True):
    """Hold the measured position (a fresh one only)."""


GripperCommand = GripperMove | GripperHold | Release


class GripEvent(Struct, frozen=True):
    """``gripper/<id>/contact``: a grip detected at the edge on the full-rate stream
    (``state`` ``grip``), or its end (``released``)."""

    stamp_ns: StampNs
    gripper: Name
    state: Literal["grip", "released"]
    q_rad: float
    target_rad: float
    error_rad: float
    tau_est: float
