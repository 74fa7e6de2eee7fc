"""The one way a key-space payload is decoded: a table of payload kinds and one helper.

Every consumer (agent, coordinator, simulator, viewer, CLI, recorder) decodes through
``PayloadKind.decode``: the size is capped before parsing, and *any* failure of the parser
becomes ``PayloadError``. msgspec raises more than ``msgspec.DecodeError`` on hostile input:
``RecursionError`` for JSON nested ~1000 deep, ``UnicodeDecodeError`` for invalid UTF-8 in a
string. A thread that catches only ``DecodeError`` dies on a 2 KB put; none may.

Size caps are per kind (``max_bytes``): generous for every real payload (the largest a command
gets is about 400 bytes), small enough that a flood of them costs little memory.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import msgspec

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


def unknown_op(data: bytes) -> str | None:
    """The ``op`` of a command payload that failed to decode, if it names no command the
    agents serve (answered 3203 "not implemented", not 3204 "bad parameter")."""
    try:
        op = _COMMAND_OP.decode(data).op
    except PayloadError:
        return None
    return None if op in m.COMMAND_OPS else op[:64]


JOINTS: PayloadKind[m.Joints] = payload_kind("joints", m.Joints, 1 * KIB)
STATUS: PayloadKind[m.ArmStatus] = payload_kind("status", m.ArmStatus, 4 * KIB)
DIAG: PayloadKind[m.Diag] = payload_kind("diag", m.Diag, 8 * KIB)
COMMAND: PayloadKind[m.ArmCommand] = payload_kind("command", m.ArmCommand, 4 * KIB)
REPLY: PayloadKind[m.CommandReply] = payload_kind("command reply", m.CommandReply, 8 * KIB)
STOP: PayloadKind[m.StopRequest] = payload_kind("stop", m.StopRequest, 4 * KIB)
RESET: PayloadKind[m.ResetRequest] = payload_kind("reset", m.ResetRequest, 1 * KIB)
STOP_ACK: PayloadKind[m.StopAck] = payload_kind("stop ack", m.StopAck, 4 * KIB)
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

PUBLIC: dict[str, PayloadKind[Any]] = {
    "arm/<arm>/joints": JOINTS,
    "arm/<arm>/status": STATUS,
    "arm/<arm>/diag": DIAG,
    "arm/<arm>/cmd (request)": COMMAND,
    "arm/<arm>/cmd (reply)": REPLY,
    "estop, arm/<arm>/estop": STOP,
    "reset, arm/<arm>/reset": RESET,
    "arm/<arm>/estop/ack": STOP_ACK,
    "heartbeat": HEARTBEAT,
    "state": STATE,
    "coordinator/cmd (request)": MULTI_REQUEST,
    "coordinator/cmd (reply)": MULTI_REPLY,
    "coordinator/diag": COORDINATOR_DIAG,
    "estop/report": STOP_REPORT,
    "arm/<arm>/contact": CONTACT,
}
"""Every public key's payload kind (``fleet schema`` prints their JSON Schemas; the README's
key-space table lists the same keys)."""
