"""Where the recorded arms and devices stand: the inventory's base poses (and what the arms'
joints read, which arm a gripper is mounted on, where a G1 stands), kept in the recording itself.

``fleet viewer --replay FILE`` draws the arms where they stood without a copy of the inventory
they were recorded with: ``fleet record`` writes the fleet's layout as an MCAP metadata record
(``d1-fleet.layout``). A file is hostile input: the layout is decoded with bounds (finite
coordinates, 7 joint signs of +-1, at most MAX_ARMS_REPORTED arms and devices, device kinds
the key space knows) or refused with a ``RecordError``. A recording made before the layout was
kept has none: its arms are taken from its keys and set in a row (``layout_from_keys``), and the
viewer says so; one made before devices were laid out has its devices taken from its keys
(``devices_from_keys``).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta, Struct

from fleet.d1.limits import GRIPPER_CLOSED_DEG, GRIPPER_OPEN_DEG, JOINT_COUNT
from fleet.devices import kind_of
from fleet.inventory import Inventory
from fleet.record.errors import RecordError
from fleet.wire import keys
from fleet.wire.messages import MAX_ARMS_REPORTED, Name

LAYOUT_METADATA = "d1-fleet.layout"
"""The metadata record's name; its one entry, ``json``, is a ``FleetLayout``."""
ROW_SPACING_M = 0.6
"""Arms of a recording without a layout stand this far apart along y (the demo's spacing)."""

Metres = Annotated[float, Meta(ge=-1000.0, le=1000.0)]
Degrees = Annotated[float, Meta(ge=-360.0, le=360.0)]


class ArmPlacement(Struct, frozen=True, forbid_unknown_fields=True):
    """One arm's base pose and joint signs (the fields of the inventory's ``[arms.<id>]``)."""

    base_xyz: tuple[Metres, Metres, Metres] = (0.0, 0.0, 0.0)
    base_rpy_deg: tuple[Degrees, Degrees, Degrees] = (0.0, 0.0, 0.0)
    joint_sign: Annotated[tuple[Literal[1, -1], ...], Meta(min_length=7, max_length=7)] = (
        1,
    ) * JOINT_COUNT
    gripper_closed_deg: Degrees = GRIPPER_CLOSED_DEG
    gripper_open_deg: Degrees = GRIPPER_OPEN_DEG


class DevicePlacement(Struct, frozen=True, forbid_unknown_fields=True):
    """One device beside the arms: its kind's key word (``gripper``, ``g1``), the arm it is
    mounted on (``""``: standing alone) and, for a G1, where it stands (``base_xyz`` None: in
    the row left of the arms, fleet/scene3d/g1_body.py)."""

    kind: Name
    mount: Name = ""
    base_xyz: tuple[Metres, Metres, Metres] | None = None
    base_yaw_deg: Degrees = 0.0


class FleetLayout(Struct, frozen=True, forbid_unknown_fields=True):
    """The recorded fleet: its name, its arms and its devices, in inventory order (a recording
    made before devices were laid out has none)."""

    fleet: Name
    arms: Annotated[dict[Name, ArmPlacement], Meta(max_length=MAX_ARMS_REPORTED)]
    devices: Annotated[dict[Name, DevicePlacement], Meta(max_length=MAX_ARMS_REPORTED)] = {}


_DECODER = msgspec.json.Decoder(FleetLayout)
MAX_LAYOUT_BYTES = 1 << 20


def layout_of(
    inventory: Inventory, arms: Iterable[str] | None = None, devices: Iterable[str] | None = None
) -> FleetLayout:
    """The layout of ``inventory``'s arms and devices (of those in ``arms`` and ``devices``,
    inventory order)."""
    chosen = None if arms is None else set(arms)
    chosen_devices = None if devices is None else set(devices)
    return FleetLayout(
        fleet=inventory.fleet,
        arms={
            arm: ArmPlacement(
                base_xyz=config.base_xyz,
                base_rpy_deg=config.base_rpy_deg,
                joint_sign=config.joint_sign,  # type: ignore[arg-type]
                gripper_closed_deg=config.gripper_closed_deg,
                gripper_open_deg=config.gripper_open_deg,
            )
            for arm, config in inventory.arms.items()
            if chosen is None or arm in chosen
        },
        devices={
            device: device_placement(config)
            for device, config in inventory.devices.items()
            if chosen_devices is None or device in chosen_devices
        },
    )


def device_placement(config: Any) -> DevicePlacement:
    """A device's placement from its inventory entry (a kind's config Struct: the fields it
    has; a gripper has a mount, a G1 a base)."""
    xyz = getattr(config, "base_xyz", None)
    return DevicePlacement(
        kind=kind_of(config).key,
        mount=getattr(config, "mount", ""),
        base_xyz=None if xyz is None else (float(xyz[0]), float(xyz[1]), float(xyz[2])),
        base_yaw_deg=getattr(config, "base_yaw_deg", 0.0),
    )


def layout_metadata(layout: FleetLayout) -> dict[str, str]:
    """The metadata record's entries for ``layout``."""
    return {"json": msgspec.json.encode(layout).decode()}


def layout_from_metadata(path: str, entries: dict[str, str]) -> FleetLayout:
    """The layout a recording's metadata record holds; RecordError (naming ``path``) if it is
    malformed, out of bounds, or names an arm that is not a valid key-space name."""
    text = entries.get("json", "")
    if len(text) > MAX_LAYOUT_BYTES:
        raise RecordError(f"{path}: the recorded fleet layout is over {MAX_LAYOUT_BYTES} bytes")
    try:
        layout = _DECODER.decode(text)
    except (msgspec.DecodeError, RecursionError, UnicodeDecodeError) as exc:
        raise RecordError(f"{path}: the recorded fleet layout is malformed: {exc}") from None
    named = (layout.fleet, *layout.arms, *layout.devices)
    bad = [name for name in named if not keys.is_name(name)]
    if bad:
        raise RecordError(f"{path}: the recorded fleet layout names {bad[0]!r}, not a name")
    for device, where in layout.devices.items():
        if where.kind not in keys.DEVICE_KINDS:
            raise RecordError(
                f"{path}: the recorded device {device!r} is of kind {where.kind!r}, "
                f"not one of {', '.join(keys.DEVICE_KINDS)}"
            )
    for arm, placement in layout.arms.items():
        if placement.gripper_closed_deg == placement.gripper_open_deg:
            raise RecordError(f"{path}: the recorded gripper range of {arm!r} is empty")
    return layout


def layout_from_keys(recorded_keys: Iterable[str]) -> FleetLayout | None:
    """For a recording without a layout: the first fleet its arm keys name, its arms in order
    of appearance, in a row along y. None when no key names an arm."""
    fleet: str | None = None
    arms: dict[str, None] = {}
    for key in recorded_keys:
        parts = key.split("/", 4)
        if len(parts) < 5 or parts[0] != "fleet" or parts[2] != "arm":
            continue
        if fleet is None and keys.is_name(parts[1]):
            fleet = parts[1]
        if parts[1] == fleet and keys.is_name(parts[3]) and len(arms) < MAX_ARMS_REPORTED:
            arms.setdefault(parts[3], None)
    if fleet is None or not arms:
        return None
    offset = (len(arms) - 1) / 2.0
    return FleetLayout(
        fleet=fleet,
        arms={
            arm: ArmPlacement(base_xyz=(0.0, (i - offset) * ROW_SPACING_M, 0.0))
            for i, arm in enumerate(arms)
        },
    )


def devices_from_keys(fleet: str, recorded_keys: Iterable[str]) -> dict[str, DevicePlacement]:
    """For a recording whose layout keeps no devices (made before they were laid out): the
    devices of ``fleet`` its keys name, in order of appearance, standing alone (a gripper's
    mount and a G1's base were not kept)."""
    space = keys.KeySpace(fleet)
    found: dict[str, DevicePlacement] = {}
    for key in dict.fromkeys(recorded_keys):  # each distinct key parsed once
        try:
            parsed = space.parse_key(key)
        except keys.KeyError_:
            continue
        if parsed.kind in keys.DEVICE_KINDS and parsed.unit not in found:
            if len(found) >= MAX_ARMS_REPORTED:
                break
            found[parsed.unit] = DevicePlacement(kind=parsed.kind)
    return found
