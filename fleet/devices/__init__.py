"""Device kinds beside the D1 arm: the registry the inventory, key space, agent, simulator,
coordinator and CLI read.

A kind is one package (``fleet/dex1``, ``fleet/g1``) with a ``kind.py`` that defines one
``DeviceKind``: its key word, its inventory table, its config Struct, its key-space payloads,
and where its agent relay and simulator live (imported only by the processes that run DDS). A
fourth kind is one new package and one line in ``_KIND_MODULES``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fleet.devices.base import DeviceBase
from fleet.wire.payloads import PayloadKind

_KIND_MODULES = ("fleet.dex1.kind", "fleet.g1.kind")


@dataclass(frozen=True, eq=False)
class DeviceKind:
    """One kind of device. ``key``: its word in the key space (``fleet/<fleet>/<key>/<id>/``);
    ``section``: its inventory table; ``config``: the Struct of one device (a ``DeviceBase``);
    ``check``: what is wrong with a config (None: fine); ``payloads``: channel -> payload kind
    (the kind's rows of ``fleet.wire.payloads.CHANNELS``: ``device_payloads(key)``);
    ``summary``: one line of ``fleet status`` from a decoded state; ``agent`` / ``sim``:
    ``module:function`` building the agent relay / the simulated device."""

    key: str
    section: str
    config: type[DeviceBase]
    check: Callable[[Any], str | None]
    payloads: dict[str, PayloadKind[Any]]
    summary: Callable[[Any], str]
    agent: str
    sim: str
    stop_actions: tuple[str, ...] = ("hold",)
    extra: dict[str, Any] = field(default_factory=dict)

    def load(self, which: str) -> Callable[..., Any]:
        """The ``agent`` or ``sim`` factory (imports the DDS side on first use)."""
        module, _, name = getattr(self, which).partition(":")
        return getattr(importlib.import_module(module), name)  # type: ignore[no-any-return]


def kinds() -> dict[str, DeviceKind]:
    """Every registered kind, by key word."""
    found = [importlib.import_module(name).KIND for name in _KIND_MODULES]
    return {k.key: k for k in found}


def kind_of(config: DeviceBase) -> DeviceKind:
    """The kind whose config Struct ``config`` is."""
    for kind in kinds().values():
        if type(config) is kind.config:
            return kind
    raise ValueError(f"{type(config).__name__} is no registered device kind")
