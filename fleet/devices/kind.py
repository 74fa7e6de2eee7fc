"""``DeviceKind``: what one kind of device declares (its ``kind.py`` builds one). Kinds import
this module, never the registry: the registry loads them by name (``fleet.devices.registry``)."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from fleet.devices.base import DeviceBase
from fleet.wire.payloads import PayloadKind


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
