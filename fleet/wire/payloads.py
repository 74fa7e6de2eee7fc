"""The one way a key-space payload is decoded: the channel table and one helper.

``CHANNELS`` maps each key kind to its Struct (a ``PayloadKind``), for the arms, every device
kind (the Dex1-1 gripper, the G1: their Structs live in their packages' ``messages`` modules,
which import nothing but ``fleet.wire.messages``) and the fleet-level keys; every consumer (agent,
coordinator, client, simulator, viewer, CLI, recorder, choreography) decodes through
``decode(kind, data)`` or the kind's own ``PayloadKind.decode``: the size is capped before
parsing, and *any* failure of the parser becomes ``PayloadError``. msgspec raises more than
``msgspec.DecodeError`` on hostile input: ``RecursionError`` for JSON nested ~1000 deep,
``UnicodeDecodeError`` for invalid UTF-8 in a string. A thread that catches only
``DecodeError`` dies on a 2 KB put; none may.

Size caps are per kind (``max_bytes``): generous for every real payload (the largest a command
gets is about 400 bytes), small enough that a flood of them costs little memory.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import msgspec

import fleet.dex1.messages as dex1
import fleet.g1.messages as g1
from fleet.wire import keys
from fleet.wire import messages as m

T = TypeVar("T")

KIB = 1024
MIB = 1024 * KIB


class PayloadError(ValueError):
    """A payload that is not a valid ``kind``: too large, not JSON, not its schema, or hostile
    (nested too deep, invalid UTF-8). The message names the kind and says why."""

    def __init__(self, kind: str, why: str) -> None:
        super().__init__(f"bad {kind} payload: {why}")
        self.kind = kind
        self.why = why


@dataclass(frozen=True)
class PayloadKind(Generic[T]):
    """One kind of payload: its Struct, its size cap and its (reused) decoder."""

    name: str
    struct: Any
    max_bytes: int
    decoder: msgspec.json.Decoder[T] = field(repr=False)

    def decode(self, data: bytes | bytearray | memoryview | str) -> T:
        """The decoded payload; raises PayloadError (and only that) for anything else."""
        size = len(data)
        if size > self.max_bytes:
            raise PayloadError(self.name, f"{size} bytes is over the {self.max_bytes} byte limit")
        try:
            return self.decoder.decode(data)
        except msgspec.DecodeError as exc:
            raise PayloadError(self.name, str(exc)) from None
        except Exception as exc:  # noqa: BLE001 - RecursionError, UnicodeDecodeError, ...: see above
            raise PayloadError(self.name, f"{type(exc).__name__}: {exc}") from None


def payload_kind(name: str, struct: type[T] | Any, max_bytes: int) -> PayloadKind[T]:
    """A payload kind with its decoder built once (for kinds outside this table, e.g. the
    simulator's fault requests)."""
    return PayloadKind(name, struct, max_bytes, msgspec.json.Decoder(struct))


class _CommandOp(msgspec.Struct):
    op: str


_COMMAND_OP: PayloadKind[_CommandOp] = payload_kind("command", _CommandOp, 4 * KIB)


def unknown_op(data: bytes, known: frozenset[str] | None = None) -> str | None:
    """The ``op`` of a command payload that failed to decode, if it names no command the
    agents serve (``known``: the arm's by default; answered 3203 "not implemented", not 3204
    "bad parameter")."""
    try:
        op = _COMMAND_OP.decode(data).op
    except PayloadError:
        return None
    return None if op in (m.COMMAND_OPS if known is None else known) else op[:64]


def ops_of(kind: PayloadKind[Any]) -> frozenset[str]:
    """The ``op`` tags of a tagged-union command kind."""
    members = typing.get_args(kind.struct) or (kind.struct,)
    return frozenset(str(c.__struct_config__.tag) for c in members)


JOINTS: PayloadKind[m.Joints] = payload_kind("joints", m.Joints, 1 * KIB)
STATUS: PayloadKind[m.ArmStatus] = payload_kind("status", m.ArmStatus, 4 * KIB)
DIAG: PayloadKind[m.Diag] = payload_kind("diag", m.Diag, 8 * KIB)
COMMAND: PayloadKind[m.ArmCommand] = payload_kind("command", m.ArmCommand, 4 * KIB)
REPLY: PayloadKind[m.CommandReply] = payload_kind("command reply", m.CommandReply, 8 * KIB)
STOP: PayloadKind[m.StopRequest] = payload_kind("stop", m.StopRequest, 4 * KIB)
RESET: PayloadKind[m.ResetRequest] = payload_kind("reset", m.ResetRequest, 1 * KIB)
STOP_ACK: PayloadKind[m.StopAck] = payload_kind("stop ack", m.StopAck, 4 * KIB)
RESET_ACK: PayloadKind[m.ResetAck] = payload_kind("reset ack", m.ResetAck, 4 * KIB)
HEARTBEAT: PayloadKind[m.Heartbeat] = payload_kind("heartbeat", m.Heartbeat, 4 * MIB)
STATE: PayloadKind[m.FleetState] = payload_kind("fleet state", m.FleetState, 4 * MIB)
MULTI_REQUEST: PayloadKind[m.MultiArmRequest] = payload_kind(
    "multi-arm request", m.MultiArmRequest, 4 * KIB
)
MULTI_REPLY: PayloadKind[m.MultiArmReply] = payload_kind(
    "multi-arm reply", m.MultiArmReply, 8 * MIB
)
STOP_REPORT: PayloadKind[m.StopReport] = payload_kind("stop report", m.StopReport, 1 * MIB)
CONTACT: PayloadKind[m.ContactEvent] = payload_kind("contact", m.ContactEvent, 2 * KIB)
COORDINATOR_DIAG: PayloadKind[m.CoordinatorDiag] = payload_kind(
    "coordinator diag", m.CoordinatorDiag, 8 * KIB
)
PROCESS_INFO: PayloadKind[m.ProcessInfo] = payload_kind("process info", m.ProcessInfo, 1 * MIB)
CHOREO: PayloadKind[m.ChoreoStatus] = payload_kind("choreography status", m.ChoreoStatus, 4 * KIB)

RAW_COMMAND: PayloadKind[dict[str, Any]] = payload_kind("raw command", dict[str, Any], 4 * KIB)
"""The agent's mirror of what it wrote to DDS: a JSON object (the D1 codec caps it at 4 KiB).
(``raw/feedback`` has no kind: it is the arm's text as read, which need not be JSON at all.)"""

DEVICE_REPLY: PayloadKind[m.DeviceReply] = payload_kind("device reply", m.DeviceReply, 8 * KIB)
GRIPPER_STATE: PayloadKind[dex1.GripperState] = payload_kind(
    "gripper state", dex1.GripperState, 4 * KIB
)
GRIPPER_COMMAND: PayloadKind[dex1.GripperCommand] = payload_kind(
    "gripper command", dex1.GripperCommand, 4 * KIB
)
GRIPPER_CONTACT: PayloadKind[dex1.GripEvent] = payload_kind(
    "gripper contact", dex1.GripEvent, 4 * KIB
)
G1_STATE: PayloadKind[g1.G1State] = payload_kind("g1 state", g1.G1State, 4 * KIB)
G1_COMMAND: PayloadKind[g1.G1Command] = payload_kind("g1 command", g1.G1Command, 4 * KIB)
G1_LOWSTATE: PayloadKind[g1.G1LowState] = payload_kind("g1 lowstate", g1.G1LowState, 8 * KIB)

CMD_REPLY = f"{keys.CMD} reply"
COORDINATOR_CMD_REPLY = f"{keys.COORDINATOR_CMD} reply"
"""Kinds of the replies to the two queryables (a reply travels on its query's key)."""

Place = tuple[str, str]
"""(unit kind, channel) of a parsed key (``keys.Key.kind``, ``keys.Key.channel``)."""


@dataclass(frozen=True)
class Channel:
    """One row of the key-space table: a key kind (``keys.JOINTS``, ``keys.STATE``,
    ``gripper/state``, ...; what a subscriber routes on), its key as
    docs/reference/keyspace.md spells it, its
    payload, and the places (unit kind, channel) of the keys it travels on: a sample on a key
    parsed to one of them is this row's payload (``channel_of``). A reply row travels on its
    query's keys (``reply``)."""

    kind: str
    key: str
    payload: PayloadKind[Any]
    places: tuple[Place, ...] = ()
    reply: bool = False


_ARM, _FLEET = keys.ARM, keys.FLEET_LEVEL


def _device_rows(kind: str, own: dict[str, PayloadKind[Any]]) -> list[Channel]:
    """A device kind's rows: its own payloads (state, command, ...) and the ones every kind
    shares with the arm (stop, reset, stop ack, diag, the command reply)."""
    shared: dict[str, PayloadKind[Any]] = {
        keys.ESTOP: STOP,
        keys.RESET: RESET,
        keys.ESTOP_ACK: STOP_ACK,
        keys.RESET_ACK: RESET_ACK,
        keys.DIAG: DIAG,
    }
    spelled = {keys.CMD: f"{kind}/<id>/cmd/<principal> (request)"}
    rows = [
        Channel(
            f"{kind}/{channel}",
            spelled.get(channel, f"{kind}/<id>/{channel}"),
            payload,
            ((kind, channel),),
        )
        for channel, payload in {**own, **shared}.items()
    ]
    reply = f"{kind}/<id>/cmd/<principal> (reply)"
    return [*rows, Channel(f"{kind}/{CMD_REPLY}", reply, DEVICE_REPLY, ((kind, keys.CMD),), True)]


DEVICE_PAYLOADS: dict[str, dict[str, PayloadKind[Any]]] = {
    keys.GRIPPER: {
        keys.STATE: GRIPPER_STATE,
        keys.CMD: GRIPPER_COMMAND,
        keys.CONTACT: GRIPPER_CONTACT,
    },
    keys.G1: {keys.STATE: G1_STATE, keys.CMD: G1_COMMAND, keys.LOWSTATE: G1_LOWSTATE},
}
"""Each device kind's own payloads by channel (what ``fleet.devices`` kinds decode with)."""

CHANNELS: dict[str, Channel] = {
    c.kind: c
    for c in (
        Channel(keys.JOINTS, "arm/<arm>/joints", JOINTS, ((_ARM, keys.JOINTS),)),
        Channel(keys.STATUS, "arm/<arm>/status", STATUS, ((_ARM, keys.STATUS),)),
        Channel(keys.DIAG, "arm/<arm>/diag", DIAG, ((_ARM, keys.DIAG),)),
        Channel(
            keys.RAW_COMMAND, "arm/<arm>/raw/command", RAW_COMMAND, ((_ARM, keys.RAW_COMMAND),)
        ),
        Channel(keys.CMD, "arm/<arm>/cmd/<principal> (request)", COMMAND, ((_ARM, keys.CMD),)),
        Channel(CMD_REPLY, "arm/<arm>/cmd/<principal> (reply)", REPLY, ((_ARM, keys.CMD),), True),
        Channel(
            keys.ESTOP, "estop, arm/<arm>/estop", STOP, ((_FLEET, keys.ESTOP), (_ARM, keys.ESTOP))
        ),
        Channel(
            keys.RESET, "reset, arm/<arm>/reset", RESET, ((_FLEET, keys.RESET), (_ARM, keys.RESET))
        ),
        Channel(keys.ESTOP_ACK, "arm/<arm>/estop/ack", STOP_ACK, ((_ARM, keys.ESTOP_ACK),)),
        Channel(keys.RESET_ACK, "arm/<arm>/reset/ack", RESET_ACK, ((_ARM, keys.RESET_ACK),)),
        Channel(keys.HEARTBEAT, "heartbeat/<principal>", HEARTBEAT, ((_FLEET, keys.HEARTBEAT),)),
        Channel(keys.STATE, "state", STATE, ((_FLEET, keys.STATE),)),
        Channel(
            keys.COORDINATOR_CMD,
            "coordinator/cmd/<principal> (request)",
            MULTI_REQUEST,
            ((_FLEET, keys.COORDINATOR_CMD),),
        ),
        Channel(
            COORDINATOR_CMD_REPLY,
            "coordinator/cmd/<principal> (reply)",
            MULTI_REPLY,
            ((_FLEET, keys.COORDINATOR_CMD),),
            True,
        ),
        Channel(
            keys.COORDINATOR_DIAG,
            "coordinator/diag",
            COORDINATOR_DIAG,
            ((_FLEET, keys.COORDINATOR_DIAG),),
        ),
        Channel(keys.STOP_REPORT, "estop/report", STOP_REPORT, ((_FLEET, keys.STOP_REPORT),)),
        Channel(keys.CHOREO, "choreo/<principal>", CHOREO, ((_FLEET, keys.CHOREO),)),
        Channel(keys.CONTACT, "arm/<arm>/contact", CONTACT, ((_ARM, keys.CONTACT),)),
        Channel(
            keys.INFO, "info/<role>/<instance> (reply)", PROCESS_INFO, ((_FLEET, keys.INFO),), True
        ),
        *(row for kind, own in DEVICE_PAYLOADS.items() for row in _device_rows(kind, own)),
    )
}
"""THE channel table: every key kind that carries a decodable payload, with its payload kind,
for every kind of unit (arm, gripper, G1) and the fleet-level keys. Every consumer (agent,
coordinator, client, recorder, Foxglove bridge, choreography, viewer, ``fleet schema``,
``echo``, ``hz``) decodes through it; docs/reference/keyspace.md lists the same keys."""

_BY_PLACE: dict[tuple[Place, bool], Channel] = {
    (place, c.reply): c for c in CHANNELS.values() for place in c.places
}


def channel_of(key: keys.Key, reply: bool = False) -> Channel | None:
    """The row of a parsed key (``KeySpace.parse_key``): what a sample on it carries, or with
    ``reply`` what a reply to a query on it carries; None for a key without a payload
    (``agent`` tokens, ``raw/feedback``, ``sim/fault``)."""
    return _BY_PLACE.get(((key.kind, key.channel), reply))


def device_payloads(kind: str) -> dict[str, PayloadKind[Any]]:
    """Every payload a device kind's keys carry, by channel (own and shared; not replies)."""
    return {
        c.places[0][1]: c.payload
        for c in CHANNELS.values()
        if not c.reply and c.places and c.places[0][0] == kind
    }


def decode(kind: str, data: bytes | bytearray | memoryview | str) -> Any:
    """The payload of a sample on a key of ``kind`` (a ``CHANNELS`` kind); raises PayloadError
    for anything that is not one. A kind with no payload (``agent``, ``raw/feedback``) is a
    bug of the caller: KeyError."""
    return CHANNELS[kind].payload.decode(data)
