"""The Zenoh key space: the only place a key expression is spelled.

Every key lives under ``fleet/<fleet>``; see docs/reference/keyspace.md for payloads and
publishers. Builders return strings; ``KeySpace.parse_key`` is the one parser: it turns any
concrete key of the fleet back into (kind, unit, channel, principal), for arms, device kinds
and the fleet-level keys alike, so subscribers on wildcards can route samples
(``parse_arm_key`` / ``parse_device_key`` are its narrow forms).
"""

from __future__ import annotations

import re

from msgspec import Struct

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_\-]{0,62}\Z")  # \Z: "$" accepts a trailing newline

# Channels under fleet/<fleet>/arm/<arm>/...
JOINTS = "joints"
STATUS = "status"
RAW_FEEDBACK = "raw/feedback"
RAW_COMMAND = "raw/command"
CMD = "cmd"
AGENT = "agent"
DIAG = "diag"
ESTOP = "estop"
ESTOP_ACK = "estop/ack"
RESET = "reset"
RESET_ACK = "reset/ack"
HEARTBEAT = "heartbeat"
CONTACT = "contact"
SIM_FAULT = "sim/fault"
LOWSTATE = "lowstate"  # a G1's rt/lowstate (joint positions, IMU) at its relay rate

# Key kinds directly under fleet/<fleet>/ (HEARTBEAT, ESTOP and RESET above serve both levels)
STATE = "state"
STOP_REPORT = "estop/report"
COORDINATOR_CMD = "coordinator/cmd"
COORDINATOR_DIAG = "coordinator/diag"
INFO = "info"  # info/<role>/<instance>: every long-running process's queryable (fleet doctor)
CHOREO = "choreo"  # choreo/<principal>: the state of that principal's choreography players

ARM_CHANNELS = (
    JOINTS,
    STATUS,
    RAW_FEEDBACK,
    RAW_COMMAND,
    CMD,
    AGENT,
    DIAG,
    ESTOP,
    ESTOP_ACK,
    RESET,
    RESET_ACK,
    CONTACT,
    SIM_FAULT,
)


# Unit kinds: the word after fleet/<fleet>/ of a per-unit key
ARM = "arm"
GRIPPER = "gripper"
G1 = "g1"
DEVICE_KINDS = (GRIPPER, G1)
"""Key words of the device kinds beside the D1 arm (``fleet/devices`` registers one kind per
word; tests/unit/test_keys.py keeps the two lists equal)."""
FLEET_LEVEL = ""
"""The ``kind`` of a parsed key directly under ``fleet/<fleet>/`` (state, estop, heartbeat...)."""
DATAGRAM = "dg"
"""``fleet/<fleet>/dg/<key>``: the datagram path's copy of a stop-path key (stops, their acks,
heartbeats). A copy on the key itself would reach every subscriber of the key on both of a
process's sessions (the router routes by key, not by path): an agent got each heartbeat four
times (measured: +0.7 % of a core idle). On its own key each copy reaches the datagram session
only, the reliable one the TCP session only."""


def datagram_key(key: str) -> str:
    """``fleet/<fleet>/<rest>`` -> ``fleet/<fleet>/dg/<rest>`` (wildcards too)."""
    root, fleet, rest = key.split("/", 2)
    return f"{root}/{fleet}/{DATAGRAM}/{rest}"


def datagram_subscription(key: str) -> str:
    """How a datagram session over UDP subscribes to ``key``'s datagram copies:
    ``*/<fleet>/dg/<rest>``, its first chunk a wildcard. A subscriber declares the non-wildcard
    start of its key as a resource, and the session then sends each put under it as "resource
    id + suffix": with ``fleet/<fleet>/dg/...`` every datagram put of the session (stops, acks,
    beats) referred to ``fleet/<fleet>/dg``, and a session that reconnected under loss and lost
    that one re-declaration had every later put dropped by the router. With no declared prefix
    every put carries its whole key, and the router sends the copies to it whole too."""
    return "*/" + datagram_key(key).split("/", 1)[1]


def is_datagram_key(key: str) -> bool:
    """A datagram copy's key (``fleet/<fleet>/dg/...``)."""
    parts = key.split("/", 3)
    return len(parts) == 4 and parts[0] == "fleet" and parts[2] == DATAGRAM


def reliable_key(key: str) -> str:
    """The key a datagram copy's key mirrors (any other key as it is)."""
    if not is_datagram_key(key):
        return key
    root, fleet, _dg, rest = key.split("/", 3)
    return f"{root}/{fleet}/{rest}"


FLEET_CHANNELS = (STATE, ESTOP, RESET, STOP_REPORT, COORDINATOR_DIAG)
"""Keys directly under ``fleet/<fleet>/`` with nothing after them."""
_NAMED_CHANNELS = ((HEARTBEAT, 1), (COORDINATOR_CMD, 1), (INFO, 2), (CHOREO, 1))
"""Fleet-level channels followed by names: ``heartbeat/<principal>``,
``coordinator/cmd/<principal>``, ``info/<role>/<instance>``, ``choreo/<principal>``."""

DEVICE_CHANNELS = (
    STATE,
    CMD,
    CONTACT,
    LOWSTATE,
    AGENT,
    DIAG,
    ESTOP,
    ESTOP_ACK,
    RESET,
    RESET_ACK,
)
"""Channels under ``fleet/<fleet>/<kind>/<device>/`` for the device kinds beside the D1 arm
(``fleet/devices``: ``gripper``, ``g1``): the same words as the arm's, one meaning each."""


class KeyError_(ValueError):  # noqa: N801 - not the builtin KeyError: a bad key expression
    """A fleet or arm name that cannot be part of a key, or a key outside the key space."""


def is_name(text: str) -> bool:
    """True for a usable fleet, arm or principal name."""
    return bool(_NAME.match(text))


def check_name(kind: str, name: str) -> str:
    """Fleet and arm names: letters, digits, ``_`` and ``-``; no ``/``, ``*``, ``$`` or spaces."""
    if not _NAME.match(name):
        raise KeyError_(
            f"{kind} name {name!r} is not usable in a key: use letters, digits, '_' or '-' "
            "(at most 63, starting with a letter or digit)"
        )
    return name


def no_principal_why(key: str) -> str:
    """Why a command on ``key`` is refused when its last chunk names no usable principal."""
    chunk = key.rpartition("/")[2]
    shown = chunk if len(chunk) <= 64 else chunk[:64] + "..."
    return (
        f"the command key's last chunk {shown!r} names no usable principal: send commands to "
        ".../cmd/<principal>, a name of letters, digits, '_' or '-' (at most 63)"
    )


class ArmKey(Struct, frozen=True):
    """A concrete per-arm key, parsed."""

    fleet: str
    arm: str
    channel: str


class Key(Struct, frozen=True):
    """Any concrete key of a fleet, parsed (``KeySpace.parse_key``).

    ``kind``: ``arm``, a device kind's word (``gripper``, ``g1``) or ``FLEET_LEVEL`` ("") for
    a key directly under the fleet; ``unit``: the arm's or device's id ("" at fleet level,
    ``<role>/<instance>`` for ``info``); ``channel``: an ``ARM_CHANNELS`` / ``DEVICE_CHANNELS``
    word, or a fleet-level one (``state``, ``estop``, ``heartbeat``, ``coordinator/cmd``...);
    ``principal``: the name a ``cmd/<principal>``, ``heartbeat/<principal>`` or
    ``coordinator/cmd/<principal>`` key ends with ("" for every other key)."""

    fleet: str
    kind: str
    unit: str
    channel: str
    principal: str = ""


class DeviceKey(Struct, frozen=True):
    """A concrete per-device key, parsed (``kind`` is a device kind's key word)."""

    fleet: str
    kind: str
    device: str
    channel: str


class KeySpace:
    """Key builders for one fleet."""

    def __init__(self, fleet: str) -> None:
        self.fleet = check_name("fleet", fleet)
        self.prefix = f"fleet/{fleet}"

    def arm(self, arm: str, channel: str) -> str:
        """``fleet/<fleet>/arm/<arm>/<channel>``; ``arm`` may be ``*`` for a subscription."""
        if arm != "*":
            check_name("arm", arm)
        if channel not in ARM_CHANNELS:
            raise KeyError_(f"unknown arm channel {channel!r}")
        return f"{self.prefix}/arm/{arm}/{channel}"

    def device(self, kind: str, device: str, channel: str) -> str:
        """``fleet/<fleet>/<kind>/<device>/<channel>`` (``device`` may be ``*``); ``kind`` is
        a device kind's key word (``gripper``, ``g1``), never ``arm``."""
        if kind == ARM:
            raise KeyError_("arms have their own keys: use KeySpace.arm")
        if kind not in DEVICE_KINDS:
            raise KeyError_(f"unknown device kind {kind!r} (known: {', '.join(DEVICE_KINDS)})")
        if device != "*":
            check_name("device", device)
        if channel not in DEVICE_CHANNELS:
            raise KeyError_(f"unknown device channel {channel!r}")
        return f"{self.prefix}/{kind}/{device}/{channel}"

    def device_command(self, kind: str, device: str, principal: str) -> str:
        """``<kind>/<device>/cmd/<principal>``: ``principal``'s commands to one device."""
        return f"{self.device(kind, device, CMD)}/{check_name('principal', principal)}"

    def parse_device_key(self, key: str, kind: str) -> DeviceKey:
        """Split ``fleet/<fleet>/<kind>/<device>/<channel>``; KeyError_ for anything else
        (``cmd/<principal>`` included: ``parse_key`` gives its principal)."""
        try:
            parsed = self.parse_key(key)
        except KeyError_:
            parsed = None
        if parsed is None or parsed.kind != kind or kind == ARM or parsed.principal:
            raise KeyError_(f"{key!r} is not a {kind} key of fleet {self.fleet!r}")
        return DeviceKey(self.fleet, kind, parsed.unit, parsed.channel)

    def all_arms(self, channel: str) -> str:
        """A wildcard over every arm for one channel."""
        return self.arm("*", channel)

    @property
    def state(self) -> str:
        """The coordinator's fleet summary."""
        return f"{self.prefix}/{STATE}"

    @property
    def estop(self) -> str:
        """Fleet-wide protective stop."""
        return f"{self.prefix}/{ESTOP}"

    @property
    def reset(self) -> str:
        """Fleet-wide operator reset (agents subscribe to it)."""
        return f"{self.prefix}/{RESET}"

    @property
    def heartbeat(self) -> str:
        """Every commander's heartbeat (``heartbeat/*``: subscribe to this)."""
        return f"{self.prefix}/{HEARTBEAT}/*"

    def heartbeat_of(self, principal: str) -> str:
        """``principal``'s heartbeat: the router lets only ``principal`` publish it, so the
        agents take the commander's identity from the key, never from the payload."""
        return f"{self.prefix}/{HEARTBEAT}/{check_name('principal', principal)}"

    def command(self, arm: str, principal: str) -> str:
        """``arm/<arm>/cmd/<principal>``: ``principal``'s commands (``arm`` may be ``*``)."""
        return f"{self.arm(arm, CMD)}/{check_name('principal', principal)}"

    def commands(self, arm: str) -> str:
        """Every principal's commands to ``arm`` (the agent's queryable)."""
        return f"{self.arm(arm, CMD)}/*"

    @property
    def coordinator_cmd(self) -> str:
        """Multi-arm commands of every principal (the coordinator's queryable)."""
        return f"{self.prefix}/{COORDINATOR_CMD}/*"

    def coordinator_command(self, principal: str) -> str:
        """``principal``'s multi-arm commands."""
        return f"{self.prefix}/{COORDINATOR_CMD}/{check_name('principal', principal)}"

    @property
    def coordinator_diag(self) -> str:
        """The coordinator's counters."""
        return f"{self.prefix}/{COORDINATOR_DIAG}"

    def choreo_of(self, principal: str) -> str:
        """``choreo/<principal>``: the state of ``principal``'s choreography players (only
        ``principal`` may put it, as its heartbeat)."""
        return f"{self.prefix}/{CHOREO}/{check_name('principal', principal)}"

    @property
    def choreo(self) -> str:
        """Every principal's choreography state (subscribe to this)."""
        return f"{self.prefix}/{CHOREO}/*"

    @property
    def stop_report(self) -> str:
        """The coordinator's per-arm timing of each stop."""
        return f"{self.prefix}/{STOP_REPORT}"

    def info(self, role: str, instance: str) -> str:
        """``info/<role>/<instance>``: one process's ProcessInfo queryable."""
        return f"{self.prefix}/{INFO}/{check_name('role', role)}/{check_name('instance', instance)}"

    @property
    def all_info(self) -> str:
        """Every process's info queryable (``fleet doctor`` queries this). Exactly the shape
        the queryables serve: a router's access control lets a query reach a queryable only
        when the query's key is within what that queryable may serve (``info/**`` reached the
        router's own queryable only: under mTLS no agent answered)."""
        return f"{self.prefix}/{INFO}/*/*"

    @property
    def everything(self) -> str:
        """Every key of this fleet (for recorders and debugging)."""
        return f"{self.prefix}/**"

    def principal_of(self, key: str) -> str:
        """The principal a heartbeat or command key ends with; raises KeyError_ otherwise."""
        principal = self.parse_key(key).principal
        if not principal:
            raise KeyError_(f"{key!r} names no principal of fleet {self.fleet!r}")
        return principal

    def parse_arm_key(self, key: str) -> ArmKey:
        """Split ``fleet/<fleet>/arm/<arm>/<channel>``; raises KeyError_ for anything else
        (``cmd/<principal>`` included: ``parse_key`` gives its principal)."""
        try:
            parsed = self.parse_key(key)
        except KeyError_:
            parsed = None
        if parsed is None or parsed.kind != ARM or parsed.principal:
            raise KeyError_(f"{key!r} is not an arm key of fleet {self.fleet!r}")
        return ArmKey(self.fleet, parsed.unit, parsed.channel)

    def parse_key(self, key: str) -> Key:
        """THE key parser: any concrete key of this fleet as a ``Key``; KeyError_ for a key
        of another fleet, a wildcard, a name that is not usable, or a channel nobody uses."""
        head = self.prefix + "/"
        key = reliable_key(key)  # a datagram copy is a sample of the key it mirrors
        if not key.startswith(head):
            raise KeyError_(f"{key!r} is not a key of fleet {self.fleet!r}")
        rest = key[len(head) :]
        if rest in FLEET_CHANNELS:
            return Key(self.fleet, FLEET_LEVEL, "", rest)
        for channel, depth in _NAMED_CHANNELS:
            names = rest[len(channel) + 1 :].split("/") if rest.startswith(channel + "/") else []
            if len(names) == depth and all(_NAME.match(n) for n in names):
                if channel == INFO:
                    return Key(self.fleet, FLEET_LEVEL, "/".join(names), channel)
                return Key(self.fleet, FLEET_LEVEL, "", channel, names[0])
        kind, _, rest = rest.partition("/")
        unit, _, channel = rest.partition("/")
        channels = ARM_CHANNELS if kind == ARM else DEVICE_CHANNELS if kind in DEVICE_KINDS else ()
        if channels and _NAME.match(unit):
            if channel in channels:
                return Key(self.fleet, kind, unit, channel)
            head, _, principal = channel.rpartition("/")
            if head == CMD and _NAME.match(principal):
                return Key(self.fleet, kind, unit, CMD, principal)
        raise KeyError_(f"{key!r} is no key of fleet {self.fleet!r}'s key space")


def parse_key(key: str) -> Key:
    """``KeySpace.parse_key`` for a key of any fleet (a recording's keys name the fleet they
    were recorded in); KeyError_ for anything that is not a key of the key space."""
    head, _, rest = key.partition("/")
    name = rest.partition("/")[0]
    if head != "fleet" or not _NAME.match(name):
        raise KeyError_(f"{key!r} is not a key of the key space (fleet/<fleet>/...)")
    return KeySpace(name).parse_key(key)
