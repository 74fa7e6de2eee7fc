"""The registry of kinds: every kind's ``kind.py``, loaded by name (importlib), so the kinds sit
beside each other and nothing below them imports them.

Two lists, one per way the agent core serves a kind: ``KIND_MODULES``, the device kinds (a
``DeviceKind``: its driver, served by the core's device server; the inventory, key space,
simulator, coordinator and CLI read them too), and ``SERVED_MODULES``, the kinds that bring
their own ``UnitServer`` (a ``ServedKind``: the D1 arm). The core builds every entry the same
way: a fourth kind is one new package and one line here."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from fleet.devices.base import DeviceBase
from fleet.devices.kind import DeviceKind

if TYPE_CHECKING:  # the agent's side of the contract: the inventory reads this module
    from fleet.devices.served import ServedKind

KIND_MODULES = ("fleet.dex1.kind", "fleet.g1.kind")
SERVED_MODULES = ("fleet.d1arm.kind",)


def kinds() -> dict[str, DeviceKind]:
    """Every registered device kind, by key word."""
    found = [importlib.import_module(name).KIND for name in KIND_MODULES]
    return {k.key: k for k in found}


def served_kinds() -> list[ServedKind]:
    """Every kind that brings its own ``UnitServer``, in the registry's order (the agent
    builds them, then serves the device kinds)."""
    return [importlib.import_module(name).KIND for name in SERVED_MODULES]


def kind_of(config: DeviceBase) -> DeviceKind:
    """The kind whose config Struct ``config`` is."""
    for kind in kinds().values():
        if type(config) is kind.config:
            return kind
    raise ValueError(f"{type(config).__name__} is no registered device kind")
