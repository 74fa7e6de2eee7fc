"""Where the recorded arms stand: the inventory's base poses (and what their joints read), kept in
the recording itself.

``fleet viewer --replay FILE`` draws the arms where they stood without a copy of the inventory
they were recorded with: ``fleet record`` writes the fleet's layout as an MCAP metadata record
(``d1-fleet.layout``). A file is hostile input: the layout is decoded with bounds (finite
coordinates, 7 joint signs of +-1, at most MAX_ARMS_REPORTED arms) or refused with a
``RecordError``. A recording made before the layout was kept has none: its arms are taken from
its keys and set in a row (``layout_from_keys``), and the viewer says so.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Annotated, Literal

import msgspec
from msgspec import Meta, Struct

from fleet.d1.limits import GRIPPER_CLOSED_DEG, GRIPPER_OPEN_DEG, JOINT_COUNT
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


class FleetLayout(Struct, frozen=True, forbid_unknown_fields=True):
    """The recorded fleet: its name and its arms, in inventory order."""

    fleet: Name
    arms: Annotated[dict[Name, ArmPlacement], Meta(max_length=MAX_ARMS_REPORTED)]


_DECODER = msgspec.json.Decoder(FleetLayout)
MAX_LAYOUT_BYTES = 1 << 20


def layout_of(inventory: Inventory, arms: Iterable[str] | None = None) -> FleetLayout:
    """The layout of ``inventory``'s arms (of those in ``arms``, inventory order)."""
    chosen = None if arms is None else set(arms)
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
    bad = [name for name in (layout.fleet, *layout.arms) if not keys.is_name(name)]
    if bad:
        raise RecordError(f"{path}: the recorded fleet layout names {bad[0]!r}, not a name")
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
