"""Device kinds beside the D1 arm: the registry the inventory, key space, agent, simulator,
coordinator and CLI read.

A kind is one package (``fleet/dex1``, ``fleet/g1``) with a ``kind.py`` that defines one
``DeviceKind`` (``fleet.devices.kind``): its key word, its inventory table, its config Struct,
its key-space payloads, and where its driver and simulator live (imported only by the processes
that run DDS). The registry (``fleet.devices.registry``) loads the kinds by name; a fourth kind
is one new package and one line in ``KIND_MODULES`` (or, for a kind that brings its own
``UnitServer`` like the D1 arm's ``fleet/d1arm``, in ``SERVED_MODULES``).

Below every kind, including the D1 arm's side of the agent (``fleet/d1arm``), the package also
holds what the kinds share with the agent core: the per-unit contract (``unit``), the latch's
rules (``safety``), the command order (``ordering``), the envelope checks (``envelope``), the
device drivers' contract (``driver``) and the served kinds' (``served``).
"""

from __future__ import annotations

from fleet.devices.kind import DeviceKind
from fleet.devices.registry import KIND_MODULES, kind_of, kinds

__all__ = ["KIND_MODULES", "DeviceKind", "kind_of", "kinds"]
