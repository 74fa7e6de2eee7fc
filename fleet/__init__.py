"""d1-fleet: fleet software for Unitree D1-550 arms (see README.md and docs/).

``from fleet import Fleet`` is the scripting API (``fleet/api.py``); it is loaded on first use so
that importing the pure packages (``fleet.d1``, ``fleet.wire``) never loads Zenoh (and mypy's
strict check of those packages does not follow into the transport code).
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["Fleet"]


def __getattr__(name: str) -> Any:
    if name == "Fleet":
        return importlib.import_module("fleet.api").Fleet
    raise AttributeError(f"module 'fleet' has no attribute {name!r}")
