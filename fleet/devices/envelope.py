"""The envelope checks every kind's commands get, in one place (the caller holds the agent's lock):
the principal and its role, duplicates / out-of-order / lifetime (``fleet/devices/ordering.py``),
the lease (``<principal>/<owner>``, takeover, release) and which owners the watchdog watches. A
kind's own checks and its write come after (``UnitServer.serve``)."""

from __future__ import annotations

import time

from fleet.devices.base import DeviceCommand
from fleet.devices.driver import Refusal
from fleet.devices.ordering import CommandOrder
from fleet.devices.safety import STAMP_AHEAD_LIMIT_S, ArmSafety, LeaseRefused, seconds_ahead
from fleet.devices.unit import IncomingQuery
from fleet.inventory import Inventory
from fleet.security_config import COMMANDERS
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode

Envelope = m.ArmCommand | DeviceCommand
"""A command with the envelope every kind shares (owner, takeover, stamp_ns, lifetime_s)."""


class Principals:
    """Who may command, and whose motion the watchdog watches."""

    def __init__(self, inventory: Inventory, heartbeats: dict[str, float]) -> None:
        self._inventory = inventory
        self.heartbeats = heartbeats
        """Heartbeat source -> when it last beat (the safety loop's table, guarded by the
        agent's lock)."""

    def check(self, item: IncomingQuery) -> str:
        """The principal of a command; raises Refusal when it names none or, with security on,
        when its role may not command arms (the router refuses those first)."""
        principal = item.principal
        if principal is None:
            why = keys.no_principal_why(str(item.query.key_expr))
            raise Refusal(ErrorCode.PARAMETER, f"{item.arm!r}: {why}")
        if self._inventory.security.enabled:
            role = self._inventory.role_of(principal)
            if role not in COMMANDERS:
                raise Refusal(
                    ErrorCode.REJECTED,
                    f"principal {principal!r} (role {role}) may not command arms",
                )
        return principal

    def watched(self, principal: str, owner: str) -> bool:
        """Motion by this owner is watched: it publishes heartbeats (a player, a mirror), or it
        is a coordinator (watched even before this agent heard its first beat)."""
        return owner in self.heartbeats or self._inventory.role_of(principal) == "coordinator"


def release(label: str, safety: ArmSafety, owner: str | None, now_s: float) -> None:
    """``owner`` gives the robot up; raises Refusal when another owner holds it. A robot held
    by nobody is already released: done, not refused (issue 26: a stop ends every lease, and
    the demo's player, releasing after each stop of its dance, filled Events and ``fleet
    diag`` with "held by nobody" refusals the user had nothing to do with)."""
    if owner is None:
        raise Refusal(ErrorCode.LEASE_INVALID, f"{label}: a release names its owner")
    if safety.release(owner):
        return
    holder = safety.holder(now_s)
    if holder is not None:
        raise Refusal(ErrorCode.LEASE_INVALID, f"{label} is held by {holder.owner}")


def check_order(
    label: str, order: CommandOrder, principal: str, owner: str | None, command: Envelope
) -> None:
    """Duplicates, out-of-order commands, commands past their lifetime and commands stamped
    far ahead of this host's clock: Refusal. A future stamp would never expire, and as the
    owner's newest it would refuse every later command of the owner as "out of order"."""
    if command.stamp_ns is not None:
        ahead_s = seconds_ahead(command.stamp_ns, time.time_ns())
        if ahead_s is not None:
            raise Refusal(
                ErrorCode.PARAMETER,
                f"target for {label} is stamped {ahead_s:.1f} s ahead of this agent's clock "
                f"(at most {STAMP_AHEAD_LIMIT_S:g} s): fix the sender's clock (NTP); not executed",
            )
    refusal = order.refusal(principal, owner, command.stamp_ns)
    if refusal is not None:
        raise Refusal(ErrorCode.OUT_OF_ORDER, f"{label}: {refusal}")
    if command.lifetime_s is not None and command.stamp_ns is not None:
        age_s = (time.time_ns() - command.stamp_ns) / 1e9
        if age_s > command.lifetime_s:
            raise Refusal(
                ErrorCode.EXPIRED,
                f"target for {label} arrived {age_s * 1000:.0f} ms after it was sent, "
                f"past its lifetime of {command.lifetime_s * 1000:.0f} ms: not executed",
            )


def check_lease(
    label: str, safety: ArmSafety, owner: str | None, takeover: bool, now: float
) -> None:
    """Refusal (3207) unless ``owner`` may move the robot now; renews or takes the lease."""
    try:
        safety.check_owner(owner, takeover, now)
    except LeaseRefused as exc:
        raise Refusal(ErrorCode.LEASE_EXISTS, f"{label} is {exc}") from None
