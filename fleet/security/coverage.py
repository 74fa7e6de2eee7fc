"""Does the generated access control let every unit's traffic through? Pure: inventory -> gaps.

The rules of ``fleet.security.acl`` are written by role; the keys each kind of unit uses come
from the channel table (``fleet.wire.payloads``). A channel added to a kind and forgotten in a
role's rules is denied by the router without a word (a G1's ``lowstate`` was: the secure demo's
G1 was never posed and never danced). ``gaps`` walks every unit of the inventory and names each
(principal, message, key) the rules do not allow; ``fleet doctor`` reports them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import zenoh

from fleet.devices import kind_of
from fleet.inventory import Inventory
from fleet.security.acl import ARM_STATE, access_control, device_agent_channels
from fleet.security_config import COMMANDERS
from fleet.wire import keys

READERS = frozenset({"operator", "maintainer", "observer"})
"""Roles that read every unit's state (the CLI, the viewer)."""


@dataclass(frozen=True)
class Gap:
    """``principal`` may not send ``message`` on ``key`` (an ingress the router denies)."""

    principal: str
    message: str
    key: str

    def __str__(self) -> str:
        return f"{self.principal} may not {self.message} {self.key}"


def _needs(inventory: Inventory) -> list[tuple[str, str, str]]:
    """(principal, message, key) that every unit's traffic needs: its agent publishes its
    state channels, serves its commands and holds its token; every commander queries its own
    commands; every reader subscribes to the state channels."""
    space = keys.KeySpace(inventory.fleet)
    units: list[tuple[str, list[str], str, str]] = []  # agent, state keys, commands, token
    for arm in inventory.arms.values():
        state = [f"{space.prefix}/arm/{arm.id}/{channel}" for channel in ARM_STATE]
        units.append((arm.agent, state, space.arm(arm.id, keys.CMD), space.arm(arm.id, keys.AGENT)))
    for device in inventory.devices.values():
        kind = kind_of(device).key
        state = [space.device(kind, device.id, c) for c in device_agent_channels(kind)]
        commands = space.device(kind, device.id, keys.CMD)
        units.append((device.agent, state, commands, space.device(kind, device.id, keys.AGENT)))
    needs = []
    for agent, state, commands, token in units:
        needs += [(agent, "put", key) for key in state]
        needs += [(agent, "declare_queryable", f"{commands}/*"), (agent, "liveliness_token", token)]
        for principal, role in inventory.principals.items():
            if role in COMMANDERS and role != "coordinator":
                needs.append((principal, "query", f"{commands}/{principal}"))
            if role in READERS:
                needs += [(principal, "declare_subscriber", key) for key in state]
    return needs


def _ingress_grants(acl: dict[str, Any]) -> dict[tuple[str, str], list[zenoh.KeyExpr]]:
    """(principal, message) -> the key expressions its rules allow on ingress."""
    rules = {rule["id"]: rule for rule in acl["rules"]}
    grants: dict[tuple[str, str], list[zenoh.KeyExpr]] = {}
    for policy in acl["policies"]:
        for rule in (rules[rule_id] for rule_id in policy["rules"]):
            if "ingress" not in rule["flows"]:
                continue
            for principal in policy["subjects"]:
                for message in rule["messages"]:
                    exprs = grants.setdefault((principal, message), [])
                    exprs += [zenoh.KeyExpr(k) for k in rule["key_exprs"]]
    return grants


def gaps(inventory: Inventory) -> list[Gap]:
    """Every key a unit's agent, a commander or a reader needs and the rules deny."""
    grants = _ingress_grants(access_control(inventory))
    found = []
    for principal, message, key in _needs(inventory):
        wanted = zenoh.KeyExpr(key)
        if not any(expr.includes(wanted) for expr in grants.get((principal, message), [])):
            found.append(Gap(principal, message, key))
    return found
