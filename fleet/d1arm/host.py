"""What the agent core gives the D1 arms' side (``ArmHost``), and the one function that builds
that side from it (``serve_arms``): the core names no part of the arm but its server.

The core keeps the I/O it shares between kinds: the agent's lock, one write lock per robot,
the DDS participant and its arm command writers, the Zenoh session and publishers, the
synchronized-start thread, the stop acks, the outbox flush and the agent's own counters.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import zenoh

from fleet.d1arm.contact_edge import ContactEdge
from fleet.d1arm.server import ArmServer, Flush, OnStill, OwnCounts, Publishers
from fleet.d1arm.serving import ArmCommands, Schedule
from fleet.d1arm.slot import ArmSlot
from fleet.d1arm.tracker import ArmTracker
from fleet.d1arm.writer import ArmWriter
from fleet.devices.envelope import Principals
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.wire.keys import KeySpace


@dataclass(frozen=True)
class ArmHost:
    """The core's services for the arms (see the module docstring)."""

    lock: threading.Lock
    guard: ThreadGuard
    stopping: threading.Event
    write_lock: Callable[[str], threading.Lock]
    dds_write: Callable[[str, str], bool]
    """Writes a D1 command text on an arm's long-lived DDS writer (the core's link)."""
    mirror: Callable[[str, str], None]
    """Puts what was written on ``raw/command`` (recorders, debugging)."""
    publishers: Mapping[str, Publishers]
    zenoh: tuple[zenoh.Session, KeySpace]
    schedule: Schedule
    principals: Principals
    on_still: OnStill
    flush: Flush
    own_counts: OwnCounts


def serve_arms(inventory: Inventory, arm_ids: list[str], host: ArmHost) -> ArmServer:
    """The arms' ``UnitServer`` for ``arm_ids``: their slots, the D1 writer, contact detection,
    their commands."""
    slots = {a: ArmSlot(ArmTracker(inventory.arm(a))) for a in arm_ids}
    writer = ArmWriter(host.lock, slots, host.write_lock, (host.dds_write, host.mirror))
    contact = ContactEdge(
        {a: inventory.arm(a) for a in arm_ids},
        host.zenoh,
        host.lock,
        writer,
        {a: inventory.calibration_path(a) for a in arm_ids},
    )
    commands = ArmCommands(
        host.lock, slots, writer, host.schedule, host.principals, host.stopping, host.flush
    )
    return ArmServer(
        host.lock,
        slots,
        (writer, host.publishers, contact, commands),
        (host.on_still, host.flush, host.own_counts),
        host.guard,
        host.stopping,
    )
