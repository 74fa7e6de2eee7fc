"""The router's access control, generated from the inventory. Pure: inventory -> JSON config.

Deny by default. Every principal of the inventory is a Zenoh ACL subject (matched by the common
name of its client certificate, or its user name), with rules that follow from its role:

- ``agent``: publishes only its own arms' and devices' state, serves only their ``cmd/*`` and
  holds only their liveliness tokens; hears stops, resets and heartbeats (a device agent is
  an ``agent`` too: ``[grippers.<id>]``/``[g1.<id>]`` ``agent``, default ``agent-<id>``);
- ``coordinator``: its own heartbeat, the fleet state, stop reports and diag, commands under its
  own name, the multi-arm queryable; hears the agents' state, stops, resets, acks and contacts;
- ``operator``: commands (to arms and devices), heartbeats and choreography state under its own
  name, stops, resets, multi-arm requests; reads everything;
- ``maintainer``: an operator who may also inject simulator faults;
- ``observer`` (the viewer by default): reads everything, may stop, may not reset or command;
- ``simulator``: serves ``sim/fault`` of the simulated arms;
- ``router``: another router of the fleet (a site router joined to a central one): everything.

Identity is in the keys: ``heartbeat/<principal>`` and ``arm/<arm>/cmd/<principal>`` are allowed
to that principal only, so a lease owner or a watched commander cannot be forged. Payloads over
``max_payload_bytes`` (4 KiB on command, stop and reset keys) are dropped at the router.
"""

from __future__ import annotations

from typing import Any

from fleet.beat_limits import max_heartbeat_bytes
from fleet.devices import kind_of
from fleet.inventory import Inventory
from fleet.security_config import Role
from fleet.wire import keys
from fleet.wire.payloads import KIB, device_payloads

PUT = ["put", "delete"]
ARM_STATE = (
    "joints",
    "status",
    "diag",
    "raw/feedback",
    "raw/command",
    "estop/ack",
    "reset/ack",
    "contact",
)
SMALL_PAYLOAD_BYTES = 4 * KIB


def _rule(rule_id: str, messages: list[str], flow: str, keys: list[str]) -> dict[str, Any]:
    return {
        "id": rule_id,
        "messages": messages,
        "flows": [flow],
        "permission": "allow",
        "key_exprs": sorted(set(keys)),
    }


def _datagram_twins(grants: list[str]) -> list[str]:
    """The datagram copies' keys of the stop-path keys among ``grants`` (stops, acks,
    heartbeats)."""
    stop_path = (f"/{keys.ESTOP}", f"/{keys.ESTOP_ACK}")
    return [
        keys.datagram_key(k)
        for k in grants
        if k.endswith(stop_path) or k.split("/")[2:3] == [keys.HEARTBEAT]
    ]


class _Grants:
    """What one principal may send (ingress) and receive (egress), by message kind."""

    def __init__(self) -> None:
        self.put: list[str] = []
        self.query: list[str] = []
        self.queryable: list[str] = []
        self.token: list[str] = []
        self.read: list[str] = []
        self.liveliness: list[str] = []

    def rules(self, name: str, fleet: str) -> list[dict[str, Any]]:
        everything = f"fleet/{fleet}/**"
        # Who may put or read a stop, its ack or a heartbeat may do the same on its datagram
        # copy's key (fleet.wire.keys.datagram_key), and nothing more.
        put = [*self.put, *_datagram_twins(self.put)]
        read = [*self.read, *_datagram_twins(self.read)]
        out = []
        if put:
            out.append(_rule(f"{name}-put", PUT, "ingress", put))
        if self.query:
            out.append(_rule(f"{name}-query", ["query"], "ingress", self.query))
            out.append(_rule(f"{name}-replies", ["reply"], "egress", self.query))
        if self.queryable:
            out.append(
                _rule(f"{name}-serve", ["declare_queryable", "reply"], "ingress", self.queryable)
            )
            out.append(_rule(f"{name}-queries", ["query"], "egress", self.queryable))
        if self.token:
            out.append(_rule(f"{name}-token", ["liveliness_token"], "ingress", self.token))
        if read:
            out.append(_rule(f"{name}-subscribe", ["declare_subscriber"], "ingress", read))
            out.append(_rule(f"{name}-read", PUT, "egress", read))
        if self.liveliness:
            live = ["declare_liveliness_subscriber", "liveliness_query"]
            out.append(_rule(f"{name}-liveliness", live, "ingress", self.liveliness))
            out.append(_rule(f"{name}-tokens", ["liveliness_token"], "egress", self.liveliness))
        # Knowing who subscribes or serves is harmless, and publishers and queriers need it.
        declarations = ["declare_subscriber", "declare_queryable"]
        out.append(_rule(f"{name}-declarations", declarations, "egress", [everything]))
        return out


def device_agent_channels(kind: str) -> list[str]:
    """What a device agent publishes for its own devices of ``kind``: every channel of the
    kind's rows in the channel table but those others send it (commands, stops, resets). From
    the table, so a kind's new channel (a G1's ``lowstate``) is granted with it."""
    received = (keys.CMD, keys.ESTOP, keys.RESET)
    return [channel for channel in device_payloads(kind) if channel not in received]


def _device_kinds(inventory: Inventory) -> list[str]:
    """The key words of the device kinds this inventory has (``gripper``, ``g1``)."""
    return sorted({kind_of(d).key for d in inventory.devices.values()})


def _grants(inventory: Inventory, principal: str, role: Role) -> _Grants:
    f = f"fleet/{inventory.fleet}"
    g = _Grants()
    kinds = _device_kinds(inventory)
    stops = [f"{f}/estop", f"{f}/arm/*/estop", *(f"{f}/{k}/*/estop" for k in kinds)]
    resets = [f"{f}/reset", f"{f}/arm/*/reset", *(f"{f}/{k}/*/reset" for k in kinds)]
    agents = [f"{f}/arm/*/agent", *(f"{f}/{k}/*/agent" for k in kinds)]
    commands = [f"{f}/arm/*/cmd/{principal}", *(f"{f}/{k}/*/cmd/{principal}" for k in kinds)]
    if role == "router":
        g.put = g.query = g.queryable = g.token = g.read = g.liveliness = [f"{f}/**"]
    elif role == "agent":
        arms = [a.id for a in inventory.arms.values() if a.agent == principal]
        g.put = [f"{f}/arm/{a}/{channel}" for a in arms for channel in ARM_STATE]
        g.queryable = [f"{f}/arm/{a}/cmd/*" for a in arms]
        g.token = [f"{f}/arm/{a}/agent" for a in arms]
        g.read = [f"{f}/estop", f"{f}/reset", f"{f}/heartbeat/*"]
        g.read += [f"{f}/arm/{a}/{channel}" for a in arms for channel in ("estop", "reset")]
        # Devices: the same, for the devices this principal's agent serves.
        own = [(kind_of(d).key, i) for i, d in inventory.devices.items() if d.agent == principal]
        g.put += [f"{f}/{k}/{d}/{channel}" for k, d in own for channel in device_agent_channels(k)]
        g.queryable += [f"{f}/{k}/{d}/cmd/*" for k, d in own]
        g.token += [f"{f}/{k}/{d}/agent" for k, d in own]
        g.read += [f"{f}/{k}/{d}/{channel}" for k, d in own for channel in ("estop", "reset")]
        # Its datagram session subscribes to every stop's datagram copy with one wildcard:
        # a lost declaration of a concrete key would make the router refer to the key by a
        # number the agent never learnt (docs/design/stop-path.md). Stops are no secret:
        # observers read them all; the agent acts on its own units' only.
        g.read.append(keys.datagram_key(f"{f}/**/{keys.ESTOP}"))
    elif role == "coordinator":
        g.put = [
            f"{f}/heartbeat/{principal}",
            f"{f}/state",
            f"{f}/estop/report",
            f"{f}/coordinator/diag",
            *stops,  # a contact policy may stop an arm
        ]
        g.query = [f"{f}/arm/*/cmd/{principal}"]
        g.queryable = [f"{f}/coordinator/cmd/*"]
        channels = ("status", "estop", "reset", "estop/ack", "contact")
        g.read = [f"{f}/arm/*/{c}" for c in channels] + [f"{f}/estop", f"{f}/reset"]
        g.read += [f"{f}/{k}/*/{c}" for k in kinds for c in ("state", "estop/ack")]
        g.liveliness = agents
    elif role in ("operator", "maintainer"):
        # A player's choreography state (the viewer shows a dance that stopped, and why) is
        # put under its own name, as its heartbeat.
        g.put = [*stops, *resets, f"{f}/heartbeat/{principal}", f"{f}/choreo/{principal}"]
        g.query = [*commands, f"{f}/coordinator/cmd/{principal}"]
        if role == "maintainer":
            g.query.append(f"{f}/arm/*/sim/fault")
        g.read = [f"{f}/**"]
        g.liveliness = agents
    elif role == "observer":
        g.put = stops
        g.read = [f"{f}/**"]
        g.liveliness = agents
    elif role == "ros2":  # `fleet ros2`: the ROS keys of fleet/ros2/grants.py
        from fleet.ros2 import grants

        g.put = [*stops, *grants.data_keys(inventory), *grants.cache_keys(inventory)]
        g.queryable = [*grants.service_keys(inventory), *grants.cache_keys(inventory)]
        g.token = [*grants.graph_keys(inventory), *grants.cache_keys(inventory)]
        g.read = [f"{f}/**"]
    elif role == "simulator":
        simulated = [a.id for a in inventory.arms.values() if a.simulated]
        g.queryable = [f"{f}/arm/{a}/sim/fault" for a in simulated]
    if inventory.ros2_section is not None and role in ("operator", "maintainer", "observer"):
        # ROS 2 clients (RViz, the ros2 CLI) of `fleet ros2`, when the inventory has [ros2]
        _ros_reader(inventory, principal, g)
    if role != "router":
        # Every long-running process answers info/<role>/<instance> (fleet.observe),
        # and fleet doctor, run as a person's principal, asks info/** for versions and clocks.
        g.queryable = [*g.queryable, f"{f}/info/*/*"]
        if role in ("operator", "maintainer", "observer"):
            g.query = [*g.query, f"{f}/info/*/*"]
    return g


def _ros_reader(inventory: Inventory, principal: str, g: _Grants) -> None:
    """A person's ROS 2 tools on the fleet's router: read ``fleet ros2``'s topics and caches,
    see and join the ROS graph; call the stop services only when ``[ros2] estop_callers``
    names them."""
    from fleet.ros2 import grants

    g.read = [*g.read, *grants.data_keys(inventory), *grants.cache_keys(inventory)]
    g.query = [*g.query, *grants.cache_keys(inventory)]
    g.liveliness = [*g.liveliness, *grants.graph_keys(inventory), *grants.cache_keys(inventory)]
    g.token = [*g.token, *grants.graph_keys(inventory)]
    if principal in inventory.ros2.estop_callers:
        g.query = [*g.query, *grants.service_keys(inventory)]


def access_control(inventory: Inventory) -> dict[str, Any]:
    """The router's ``access_control`` section for ``inventory``."""
    field = "cert_common_names" if inventory.security.mode == "mtls" else "usernames"
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for principal, role in sorted(inventory.principals.items()):
        own = _grants(inventory, principal, role).rules(principal, inventory.fleet)
        rules += own
        subjects.append({"id": principal, field: [principal]})
        policies.append(
            {"id": f"{principal}-policy", "rules": [r["id"] for r in own], "subjects": [principal]}
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def payload_limits(inventory: Inventory) -> list[dict[str, Any]]:
    """The router's ``low_pass_filter`` (in every security mode): small messages on command,
    stop and reset keys, heartbeats bounded by the fleet's size, and ``max_payload_bytes`` on
    everything else."""
    f = f"fleet/{inventory.fleet}"
    small = [
        f"{f}/arm/*/cmd/**",
        f"{f}/coordinator/cmd/**",
        f"{f}/estop",
        f"{f}/arm/*/estop",
        f"{f}/reset",
        f"{f}/arm/*/reset",
    ]
    for kind in _device_kinds(inventory):
        small += [f"{f}/{kind}/*/cmd/**", f"{f}/{kind}/*/estop", f"{f}/{kind}/*/reset"]
    small += _datagram_twins(small)
    # Every kind's command, stop and reset keys. zenoh 1.10's low-pass filter
    # (zenoh/src/net/routing/interceptor/low_pass.rs) takes, per message, the smallest
    # size_limit among the filter keys that include the message's key: it only ever drops
    # messages over a limit, so these keys cannot stop small traffic
    # (tests/e2e/test_router_limits.py and the secure demo pass with them; the break reported
    # with 4319b77 did not reproduce).
    messages = ["put", "delete", "query", "reply"]
    beat = max_heartbeat_bytes(len(inventory.arms) + len(inventory.devices))
    return [
        {
            "id": "commands",
            "messages": messages,
            "key_exprs": small,
            "size_limit": SMALL_PAYLOAD_BYTES,
        },
        {  # a heartbeat repeats at most every unit's stop (fleet.beat_limits)
            "id": "heartbeats",
            "messages": messages,
            "key_exprs": [f"{f}/heartbeat/*", keys.datagram_key(f"{f}/heartbeat/*")],
            "size_limit": beat,
        },
        {
            "id": "everything",
            "messages": messages,
            "key_exprs": ["**"],
            "size_limit": inventory.security.max_payload_bytes,
        },
    ]
