"""The D1 arm as a kind the agent core builds (``KIND``, listed in ``fleet.devices.registry``):
``build`` makes the arms' whole side of the agent from what the core shares with every kind
(``CoreServices``): their DDS readers and writers (``link``), their Zenoh publishers
(``publishers``), their slots, the D1 writer, contact detection and commands, and their
``UnitServer`` (``server``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fleet.d1arm.contact_edge import ContactEdge
from fleet.d1arm.link import ArmLink
from fleet.d1arm.publishers import ArmOutlets
from fleet.d1arm.server import ArmServer
from fleet.d1arm.serving import ArmCommands
from fleet.d1arm.slot import ArmSlot
from fleet.d1arm.tracker import ArmTracker
from fleet.d1arm.writer import ArmWriter
from fleet.devices.served import CoreServices, ServedKind
from fleet.inventory import Inventory
from fleet.wire.keys import ARM


@dataclass(frozen=True)
class ArmSide:
    """The arms' side of one agent (a ``fleet.devices.served.KindSide``)."""

    server: ArmServer
    units: dict[str, ArmSlot]
    link: ArmLink
    outlets: ArmOutlets

    def close(self) -> None:
        """Undeclare the arms' publishers."""
        self.outlets.close()


def build(inventory: Inventory, unit_ids: Sequence[str], core: CoreServices) -> ArmSide:
    """The side of the arms among ``unit_ids`` (none: an empty side, its ``files`` thread
    idle)."""
    arm_ids = [u for u in unit_ids if u in inventory.arms]
    link = ArmLink(*core.dds, {a: inventory.arm(a).suffix for a in arm_ids})
    outlets = ArmOutlets(core.zenoh, arm_ids, core.guard)
    slots = {a: ArmSlot(ArmTracker(inventory.arm(a))) for a in arm_ids}
    writer = ArmWriter(core.lock, slots, core.write_lock, (link.write, outlets.mirror))
    contact = ContactEdge(
        {a: inventory.arm(a) for a in arm_ids},
        core.zenoh,
        core.lock,
        writer,
        {a: inventory.calibration_path(a) for a in arm_ids},
    )
    commands = ArmCommands(
        core.lock, slots, writer, core.schedule, core.principals, core.stopping, core.flush
    )
    server = ArmServer(
        core.lock,
        slots,
        (writer, outlets.by_arm, contact, commands),
        (core.on_still, core.flush, core.own_counts),
        core.guard,
        core.stopping,
    )
    # Bound once: the relay thread hands every feedback sample straight to the server.
    link.serve(server.on_feedback, server.on_bad_sample)
    return ArmSide(server, slots, link, outlets)


KIND = ServedKind(ARM, build)
