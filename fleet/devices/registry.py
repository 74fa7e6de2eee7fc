"""The registry of device kinds: every kind's ``kind.py``, loaded by name (importlib), so the
kinds sit beside each other and nothing below them imports them. A fourth kind is one new
package and one line in ``KIND_MODULES``."""

from __future__ import annotations

import importlib

from fleet.devices.base import DeviceBase
from fleet.devices.kind import DeviceKind

KIND_MODULES = ("fleet.dex1.kind", "fleet.g1.kind")


def kinds() -> dict[str, DeviceKind]:
    """Every registered kind, by key word."""
    found = [importlib.import_module(name).KIND for name in KIND_MODULES]
    return {k.key: k for k in found}


def kind_of(config: DeviceBase) -> DeviceKind:
    """The kind whose config Struct ``config`` is."""
    for kind in kinds().values():
        if type(config) is kind.config:
            return kind
    raise ValueError(f"{type(config).__name__} is no registered device kind")
