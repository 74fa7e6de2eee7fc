"""What the viewer sends: STOP ALL or one arm's or device's stop, resets, jog (``move_joint``)
commands, and device commands (the gripper's opening, the G1's damp and stop move).

Jogs and device commands go through ``FleetClient.command`` / ``device_command`` on the
viewer's own ``viewer-jog`` thread: a GUI callback only records the newest target per (arm,
joint) or per device and returns (latest wins: dragging a slider never queues up a backlog of
moves). Both carry the viewer's ``owner``, so they take the arm's or device's lease.

A stop is put at once, from the caller's thread (a viser callback thread, never a Zenoh one), with
congestion control BLOCK and priority REAL_TIME; the ``viewer-stop`` thread then hands it to
``FleetClient.estop``, which re-puts it (same ``stop_id``: agents ignore repeats) until every arm
acknowledged and was seen still, and the operator is told which arms did not confirm.

Every command leaves through one ``FleetClient`` built on the viewer's inventory, so it acts as
the viewer's principal (``inventory.principal``: ``viewer`` unless ``--principal`` says
otherwise; jogs go to ``arm/<arm>/cmd/<principal>``). A *read-only* viewer (``--read-only``, or
a principal whose role may not command: the default ``viewer`` is an ``observer``) may only
stop: ``jog``, ``device`` and ``reset`` refuse here, whatever the browser sends.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import socket
import threading
import time
from collections.abc import Callable

import msgspec
import zenoh

from fleet.client import FleetClient
from fleet.d1.limits import JOINT_RANGE_DEG, JointRanges
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.security_config import COMMANDERS
from fleet.web.refusals import Refusals
from fleet.wire import keys
from fleet.wire import messages as m

log = logging.getLogger("viewer.commands")

STOP_CONFIRM_S = 3.0
"""How long the viewer waits for every arm to acknowledge a stop and be seen still."""
RESET_ANSWER_S = 3.0
"""How long the viewer waits for every unit's answer to a reset (``reset/ack``)."""
RESETS_WAITING = 8
"""Resets waiting for the ``viewer-reset`` thread; one more is refused (a stuck button)."""

Notify = Callable[[str, str, bool], None]
"""``notify(title, body, is_error)``: show a notification in every connected browser."""


def may_command(inventory: Inventory) -> bool:
    """True when the inventory's principal has a role that may command arms and reset stops
    (operator, maintainer, coordinator); an observer, or a principal the inventory does not
    know, may only stop."""
    return inventory.role_of(inventory.principal) in COMMANDERS


def clamp_to_limits(joint: int, angle_deg: float, ranges: JointRanges = JOINT_RANGE_DEG) -> float:
    """``angle_deg`` clamped to wire joint ``joint``'s range (``ranges``: the arm's)."""
    low, high = ranges[joint]
    return min(max(angle_deg, low), high)


MAX_JOG_STEP_DEG = 10.0
"""One jog moves a joint at most this far from where the arm measures it: typing 1 into a slider
that showed a stale -37 moved the joint 38 deg in one step."""
JOG_INTERVAL_S = 0.25
"""At most one jog per arm in this interval (the newest target wins): with the step above, a
dragged slider moves a joint at most 40 deg/s."""


def jog_target(
    joint: int, requested_deg: float, measured_deg: float, ranges: JointRanges = JOINT_RANGE_DEG
) -> float:
    """Where a jog may go: towards ``requested_deg``, at most MAX_JOG_STEP_DEG from the measured
    angle, inside the joint's limits (``ranges``: the arm's, its gripper's own)."""
    step = min(max(requested_deg - measured_deg, -MAX_JOG_STEP_DEG), MAX_JOG_STEP_DEG)
    return clamp_to_limits(joint, measured_deg + step, ranges)


DEVICE = -1
"""The slot of a device's pending command (an arm's slots are its joints)."""


def device_op(command: m.DeviceCommand) -> str:
    """The ``op`` of a device command (``move``, ``damp``, ...)."""
    return str(type(command).__struct_config__.tag)


class Commander:
    """The viewer's outgoing side on the key space. A context manager; ``close()`` idempotent."""

    def __init__(
        self,
        inventory: Inventory,
        session: zenoh.Session,
        notify: Notify,
        guard: ThreadGuard | None = None,
        read_only: bool = False,
    ) -> None:
        self.keys = keys.KeySpace(inventory.fleet)
        self.client = FleetClient(inventory, session=session)
        self.principal = inventory.principal
        self.read_only = read_only or not may_command(inventory)
        self.refusals = Refusals(log)
        self._notify = notify
        self._lock = threading.Lock()  # guards _pending only
        # (arm, joint) -> its jog target; (device, DEVICE) -> the device's newest command
        self._pending: dict[tuple[str, int], m.MoveJoint | m.DeviceCommand] = {}
        self._last_jog_s: dict[str, float] = {}
        self._answered: set[str] = set()
        # The viewer moves arms as an owner like any other: its jogs take the arm's lease, so a
        # script cannot move the arm under the operator's hand (nor the viewer under a script's).
        self.owner = f"viewer@{socket.gethostname()}:{os.getpid()}"
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._stops: queue.SimpleQueue[tuple[m.StopRequest, str | None] | None] = (
            queue.SimpleQueue()
        )
        self._resets: queue.Queue[str | None] = queue.Queue(RESETS_WAITING + 1)
        """Units to reset ("": every one); None ends the thread."""
        guard = guard or ThreadGuard("viewer")
        self._threads = [
            guard.thread(self._jog_loop, "viewer-jog"),
            guard.thread(self._stop_loop, "viewer-stop"),
            guard.thread(self._reset_loop, "viewer-reset"),
        ]
        for thread in self._threads:
            thread.start()

    # ------------------------------------------------------------------ stop and reset

    def stop(self, arm: str | None = None, reason: str = "") -> m.StopRequest:
        """Put a StopRequest for ``arm`` (None: every arm) now; its repeats and confirmation
        follow on the ``viewer-stop`` thread. Drops pending jogs and device commands (of that arm
        or device, and of the devices mounted on that arm)."""
        where = "every arm and device" if arm is None else arm
        reason = reason or f"{'STOP ALL' if arm is None else 'stop ' + arm} pressed in the viewer"
        devices = self.client.inventory.devices
        # An arm's stop stops what is mounted on it: its pending commands go too.
        mounted = {d for d, c in devices.items() if getattr(c, "mount", "") == arm}
        with self._lock:
            for key in [k for k in self._pending if arm is None or k[0] in {arm, *mounted}]:
                del self._pending[key]
        request = self.client.stop_request(reason, source="viewer")
        # estop/put_stop take an arm or a device id (a device's stop: its own key only)
        self.client.put_stop(request, arm)
        self._stops.put((request, arm))
        log.warning("stop of %s sent (stop_id %s)", where, request.stop_id)
        return request

    def reset(self, arm: str | None = None) -> bool:
        """Put a ResetRequest for ``arm`` (an arm or a device id; None: every arm and device;
        the operator confirmed it); False,
        sending nothing, when the viewer is read-only."""
        if self._refused("reset"):
            return False
        where = "the whole fleet" if arm is None else arm
        if self._resets.qsize() >= RESETS_WAITING:
            self._notify(f"reset {where}: not sent", "too many resets waiting: try again", True)
            return False
        self._resets.put(arm or "")
        return True

    def _reset_loop(self) -> None:
        """Put each reset and tell the operator what it did to each unit (its agents'
        ``reset/ack``): released, still stopped and why, or no answer."""
        while True:
            item = self._resets.get()
            if item is None or self._closing.is_set():
                return
            arm = item or None
            where = "the whole fleet" if arm is None else arm
            log.warning("reset of %s put (principal %s)", where, self.principal)
            answers = self.client.reset_and_report(arm, source="viewer", timeout_s=RESET_ANSWER_S)
            silent = [u for u, a in answers.items() if a is None]
            kept = [
                f"{u} ({a.detail})"
                for u, a in answers.items()
                if a and a.outcome in ("kept", "refused")
            ]
            released = [u for u, a in answers.items() if a is not None and a.outcome == "released"]
            if kept or silent:
                body = "; ".join(
                    [f"still stopped: {', '.join(kept)}"] * bool(kept)
                    + [f"no answer from {', '.join(silent)} (agent down?)"] * bool(silent)
                )
                self._notify(f"reset {where}: not every unit released", body, True)
            else:
                done = f"released {', '.join(released)}" if released else "nothing was stopped"
                self._notify(f"reset {where}", done, False)

    def _refused(self, what: str) -> bool:
        if not self.read_only:
            return False
        self.refusals.refuse(
            what, f"{what}: this viewer is read-only (principal {self.principal!r}): STOP only"
        )
        return True

    def _stop_loop(self) -> None:
        while True:
            item = self._stops.get()
            if item is None or self._closing.is_set():
                return
            request, arm = item
            acks = self.client.estop(arm, request=request, timeout_s=STOP_CONFIRM_S)
            unconfirmed = [a for a, ack in acks.items() if ack is None or not ack.done]
            title = "STOP ALL" if arm is None else f"stop {arm}"
            if unconfirmed:
                self._notify(
                    f"{title}: not confirmed",
                    f"no acknowledgment or standstill from {', '.join(unconfirmed)}: "
                    "check those arms (their agents may be down)",
                    True,
                )
            else:
                every = "every arm and device" if arm is None else arm
                self._notify(title, f"{every} acknowledged and is still", False)

    # ------------------------------------------------------------------ jog

    def joint_ranges(self, arm: str) -> JointRanges:
        """``arm``'s joint ranges (its gripper's own reading)."""
        return self.client.inventory.arm(arm).joint_ranges_deg

    def jog(self, arm: str, joint: int, angle_deg: float, measured_deg: float) -> bool:
        """Ask for ``arm``'s ``joint`` towards ``angle_deg``, one bounded step from the measured
        ``measured_deg`` (``jog_target``); returns at once. False, sending nothing, when the
        viewer is read-only."""
        if self._refused("jog"):
            return False
        ranges = self.joint_ranges(arm)
        target = jog_target(joint, angle_deg, measured_deg, ranges)
        with self._lock:
            self._pending[(arm, joint)] = m.MoveJoint(
                joint=joint, angle_deg=target, owner=self.owner
            )
        self._wake.set()
        return True

    def device(self, device: str, command: m.DeviceCommand) -> bool:
        """Send ``command`` (a kind's command Struct) to ``device`` under the viewer's lease
        (its ``owner``); returns at once, the newest command per device wins. False, sending
        nothing, when the viewer is read-only."""
        if self._refused(device_op(command)):
            return False
        self.client.inventory.device(device)  # unknown device: InventoryError, now
        with self._lock:
            self._pending[(device, DEVICE)] = msgspec.structs.replace(command, owner=self.owner)
        self._wake.set()
        return True

    def _jog_loop(self) -> None:
        while not self._closing.is_set():
            if not self._wake.wait(0.2):
                continue
            self._wake.clear()
            now = time.monotonic()
            with self._lock:
                due = {k: v for k, v in self._pending.items() if self._jog_due(k[0], now)}
                for key in due:
                    del self._pending[key]
                if self._pending:
                    self._wake.set()  # the rest when their arm's interval has passed
            for (unit, _slot), command in due.items():
                if self._closing.is_set():
                    return
                with self._lock:
                    self._last_jog_s[unit] = now
                if isinstance(command, m.MoveJoint):
                    self._send_jog(unit, command)
                else:
                    self._send_device(unit, command)
                with self._lock:
                    self._answered.add(unit)
            if self._pending:
                time.sleep(JOG_INTERVAL_S / 5)

    def answered(self, unit: str) -> bool:
        """True once ``unit`` (arm or device) answered a jog or device command of this viewer:
        its agent has taken or refused it (and so its lease) by then."""
        with self._lock:
            return unit in self._answered

    def _jog_due(self, arm: str, now: float) -> bool:
        return now - self._last_jog_s.get(arm, -JOG_INTERVAL_S) >= JOG_INTERVAL_S

    def _send_jog(self, arm: str, command: m.MoveJoint) -> None:
        reply = self.client.command(arm, command)
        if reply.ok:
            return
        why = reply.error.message if reply.error else "refused"
        joint, angle_deg = command.joint, command.angle_deg
        log.warning("jog of %s joint %d to %.1f deg failed: %s", arm, joint, angle_deg, why)
        self._notify(f"{arm}: move_joint {joint} failed", why, True)

    def _send_device(self, device: str, command: m.DeviceCommand) -> None:
        reply = self.client.device_command(device, command)
        if reply.ok:
            return
        why = reply.error.message if reply.error else "refused"
        log.warning("%s of %s failed: %s", device_op(command), device, why)
        self._notify(f"{device}: {device_op(command)} failed", why, True)

    # ------------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Stop the threads (join with a timeout), then undeclare the publishers."""
        if self._closing.is_set():
            return
        self._closing.set()
        self._wake.set()
        self._stops.put(None)
        with contextlib.suppress(queue.Full):  # full: it sees _closing after its current reset
            self._resets.put_nowait(None)
        for thread in self._threads:
            thread.join(timeout=5.0)

    def __enter__(self) -> Commander:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
