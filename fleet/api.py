"""``from fleet import Fleet``: the Python API users script the fleet with.

A thin layer over ``FleetClient`` and the public key space: every call is a documented query
or put (a Zenoh client in another language can do the same). One owner id per ``Fleet``: its
moves take the arms' leases; leaving the ``with`` block releases them and closes the session.

    with Fleet("inventory.toml") as fleet:
        fleet.arms["a1"].move(angles_deg=[0, -30, 45, 0, 30, 0, 20], wait=True)
        fleet.group("left").move(angles_deg=[0, 0, 0, 0, 0, 0, 30], wait=True)
        print(fleet.arms["a2"].joints())
"""

from __future__ import annotations

import os
import socket
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import msgspec

from fleet.client import FleetClient, start_at_ns
from fleet.inventory import Inventory, load_inventory
from fleet.watch import ArmWatch
from fleet.wire import messages as m


def _move_joints(
    angles_deg: list[float],
    wait: bool,
    mode: int,
    timeout_s: float,
    tolerance_deg: float = 2.0,
    start_at_ns: int | None = None,
) -> m.MoveJoints:
    """The ``move_joints`` an arm's or a group's ``move`` sends (mode 1 unless 0 is asked)."""
    return m.MoveJoints(
        angles_deg=list(angles_deg),
        mode=1 if mode else 0,
        wait_reached=wait,
        timeout_s=timeout_s,
        tolerance_deg=tolerance_deg,
        start_at_ns=start_at_ns,
    )


class CommandFailed(RuntimeError):
    """An arm refused or failed a command; ``reply`` is the agent's CommandReply."""

    def __init__(self, reply: m.CommandReply) -> None:
        error = reply.error
        super().__init__(
            f"arm {reply.arm!r}: [{error.code if error else '?'}] {error.message if error else ''}"
        )
        self.reply = reply


class Arm:
    """One arm of a ``Fleet``."""

    def __init__(self, fleet: Fleet, arm_id: str) -> None:
        self.fleet = fleet
        self.id = arm_id

    def command(self, command: m.ArmCommand, check: bool = True) -> m.CommandReply:
        """Send any key-space command as this fleet's owner; CommandFailed unless ok (check)."""
        reply = self.fleet.client.command(self.id, self.fleet._owned(self.id, command))
        if check and not reply.ok:
            raise CommandFailed(reply)
        return reply

    def move(
        self,
        angles_deg: list[float],
        wait: bool = False,
        mode: int = 1,
        timeout_s: float = 10.0,
        tolerance_deg: float = 2.0,
        check: bool = True,
    ) -> m.CommandReply:
        """Move all seven joints (degrees, wire ids 0..6); ``wait``: until feedback shows it."""
        command = _move_joints(angles_deg, wait, mode, timeout_s, tolerance_deg=tolerance_deg)
        return self.command(command, check)

    def move_joint(self, joint: int, angle_deg: float, wait: bool = False) -> m.CommandReply:
        """Move one joint (wire id 0..6)."""
        return self.command(m.MoveJoint(joint=joint, angle_deg=angle_deg, wait_reached=wait))

    def hold(self) -> m.CommandReply:
        """Hold the measured pose (allowed while stopped)."""
        return self.command(m.Hold())

    def torque(self, on: bool, joint: int | None = None) -> m.CommandReply:
        """Enable or unload (``on=False``: the arm can be moved by hand, or falls!)."""
        return self.command(m.Torque(on=on, joint=joint))

    def stop(self, reason: str = "") -> m.StopAck | None:
        """Protective stop of this arm; returns its acknowledgment (None: no ack)."""
        return self.fleet.client.estop(self.id, reason=reason, source=self.fleet.owner)[self.id]

    def joints(self) -> list[float] | None:
        """The latest measured angles (degrees), None before the first sample."""
        latest = self.fleet._watch.latest(self.id).joints
        return list(latest.angles_deg) if latest is not None else None

    def status(self) -> m.ArmStatus | None:
        """The latest status its agent published, None before the first one."""
        return self.fleet._watch.latest(self.id).status

    def __repr__(self) -> str:
        return f"Arm({self.id!r})"


class Group:
    """Several arms moved together with one synchronized start."""

    def __init__(self, fleet: Fleet, name: str, arm_ids: list[str]) -> None:
        self.fleet = fleet
        self.name = name
        self.arms = [fleet.arms[a] for a in arm_ids]

    def move(
        self, angles_deg: list[float], wait: bool = False, mode: int = 1, timeout_s: float = 10.0
    ) -> dict[str, m.CommandReply]:
        """Every arm to the same pose, all starting at the same instant (``start_at_ns``, the
        inventory's ``sync_lead_s`` ahead, as the coordinator's synchronized starts). Raises
        CommandFailed for the first arm that failed (after all replied)."""
        start_ns = start_at_ns(self.fleet.inventory.coordinator.sync_lead_s)
        command = _move_joints(angles_deg, wait, mode, timeout_s, start_at_ns=start_ns)
        replies = dict(
            zip(
                [a.id for a in self.arms],
                self.fleet._pool.map(lambda a: a.command(command, check=False), self.arms),
            )
        )
        for reply in replies.values():
            if not reply.ok:
                raise CommandFailed(reply)
        return replies


class Fleet:
    """A connection to one fleet. A context manager; ``close()`` releases and disconnects."""

    def __init__(
        self,
        inventory: str | Path | Inventory = "inventory.toml",
        endpoints: list[str] | None = None,
        owner: str | None = None,
    ) -> None:
        inv = inventory if isinstance(inventory, Inventory) else load_inventory(inventory)
        if endpoints:
            inv = inv.with_endpoints(list(endpoints))
        self.inventory = inv
        self.owner = owner or f"api@{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"
        self.client = FleetClient(inv)
        self._watch = ArmWatch(self.client.session, self.client.keys, inv.arms)
        self._pool = ThreadPoolExecutor(max_workers=8, thread_name_prefix="fleet-api")
        self._used: set[str] = set()
        self._lock = threading.Lock()  # guards self._used
        self._closed = False
        self.arms: dict[str, Arm] = {a: Arm(self, a) for a in inv.arms}

    def _owned(self, arm: str, command: m.ArmCommand) -> m.ArmCommand:
        with self._lock:
            self._used.add(arm)
        return msgspec.structs.replace(command, owner=self.owner)

    def group(self, name: str) -> Group:
        """An inventory group, an arm id, or ``all``."""
        return Group(self, name, self.inventory.resolve(name))

    def stop(self, reason: str = "") -> dict[str, m.StopAck | None]:
        """Protective stop of every arm; waits for acks and standstill (see FleetClient)."""
        return self.client.estop(reason=reason, source=self.owner)

    def reset(self, arm: str | None = None) -> None:
        """Release the stop latch (operator action; never moves an arm)."""
        self.client.reset(arm, source=self.owner)

    def wait_for_arms(self, timeout_s: float = 10.0) -> bool:
        """Wait until every arm reported joints and an ok link; False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            statuses = [a.status() for a in self.arms.values()]
            if all(s is not None and s.link == "ok" for s in statuses) and all(
                a.joints() is not None for a in self.arms.values()
            ):
                return True
            time.sleep(0.05)
        return False

    def close(self) -> None:
        """Release every arm this fleet commanded, then close the session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        with self._lock:
            used = sorted(self._used)
        for arm in used:
            self.client.command(arm, m.Release(owner=self.owner))
        self._pool.shutdown(wait=True)
        self._watch.close()
        self.client.close()

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
