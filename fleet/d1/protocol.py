"""The D1-550 JSON protocol as a pure codec: text <-> typed commands and arm messages.

No I/O, clocks, logging or threads live here (the h11 model): the edge agent, the simulated arm,
the coordinator and the tests all speak the protocol through these functions.

Wire facts (``../shared/seeds`` D1 service interface):
- every message is ``{"seq":..,"address":..,"funcode":..,"data":{..}}``; ``data`` is absent for
  return-to-zero (1/7);
- commands use address 1; the arm's own reports use address 2 with seq 10; its acknowledgments
  (address 3) echo the seq of the command they answer;
- numbers are written as the spec writes them: an integral value as an integer (``60``, not
  ``60.0``), so the spec's examples are reproduced byte for byte.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import msgspec

from fleet.d1.errors import InvalidCommand, InvalidJoint, MalformedMessage, UnknownMessage
from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG, TORQUE_MODE_MAX, JointRanges

MAX_MESSAGE_BYTES = 4096
"""The longest D1 string accepted either way: the spec's longest is about 170 bytes; a DDS string
has no bound of its own, and a peer's megabyte must not be parsed on the feedback thread."""

ARM_REPORT_SEQ = 10
"""The seq the arm hard-codes on its own reports; callers must never use it."""

COMMAND_ADDRESS = 1
REPORT_ADDRESS = 2
ACK_ADDRESS = 3


# ----------------------------------------------------------------------------- commands


class SetJointAngle(msgspec.Struct, frozen=True):
    """1/1: move one joint to ``angle_deg``. ``delay_ms`` is documented as "temporarily 0"."""

    joint: int
    angle_deg: float
    delay_ms: int = 0


class SetAllAngles(msgspec.Struct, frozen=True):
    """1/2: move all seven joints. ``mode`` 0 = small smoothing (10 Hz streaming), 1 = large."""

    angles_deg: tuple[float, ...]
    mode: Literal[0, 1] = 1


class SetJointTorque(msgspec.Struct, frozen=True):
    """1/4: enable (lock) or unload (free) one joint motor."""

    joint: int
    enable: bool


class SetAllTorque(msgspec.Struct, frozen=True):
    """1/5: all joint motors. ``mode`` 0 = unloaded, 1 = enabled; the spec also allows
    0..80000 as a holding strength (80000 = fully locked)."""

    mode: int


class SetPower(msgspec.Struct, frozen=True):
    """1/6: switch the motors' power supply."""

    on: bool


class ReturnToZero(msgspec.Struct, frozen=True):
    """1/7: return every joint to zero."""


Command = SetJointAngle | SetAllAngles | SetJointTorque | SetAllTorque | SetPower | ReturnToZero

"""Commands that make the arm move (refused while stopped, need power)."""

_FUNCODE_OF: dict[type, int] = {
    SetJointAngle: 1,
    SetAllAngles: 2,
    SetJointTorque: 4,
    SetAllTorque: 5,
    SetPower: 6,
    ReturnToZero: 7,
}


# ----------------------------------------------------------------------------- arm messages


class JointAngles(msgspec.Struct, frozen=True):
    """2/1: the measured angle of every joint, degrees, about 10 Hz."""

    angles_deg: tuple[float, ...]


ERROR_STATUS_NORMAL = 1
"""``error_status`` 1 is "normal". The table says 0 is "abnormal"; the contact plan expects a
bitfield of fault flags: every value but 1 is read as abnormal, and the raw value is kept."""

ERROR_STATUS_RANGE = (-(2**63), 2**64 - 1)
"""The integers accepted as ``error_status``: any 64-bit value, signed or not (a bitfield of a
C integer); a longer one is garbage, not a flag set."""


class D1Status(msgspec.Struct, frozen=True):
    """2/3: the arm's own enable and power report with its raw ``error_status``. (Not the key
    space's ``fleet.wire.messages.ArmStatus``, which the agent builds from this, the link state
    and its latch.)"""

    enabled: bool
    powered: bool
    error_status: int = ERROR_STATUS_NORMAL

    @property
    def error(self) -> bool:
        """The arm reports something abnormal: ``error_status`` is not 1."""
        return self.error_status != ERROR_STATUS_NORMAL


class MotorStatus(msgspec.Struct, frozen=True):
    """2/4: per-motor health, True = normal."""

    motors_ok: tuple[bool, ...]


class ReceiveAck(msgspec.Struct, frozen=True):
    """3/1: the arm received (and could parse) the command with this ``seq``."""

    seq: int
    ok: bool


class ExecuteAck(msgspec.Struct, frozen=True):
    """3/2: the arm executed the command with this ``seq``."""

    seq: int
    ok: bool


ArmMessage = JointAngles | D1Status | MotorStatus | ReceiveAck | ExecuteAck


class Decoded(msgspec.Struct, frozen=True):
    """A decoded arm message with the names of any fields the spec does not define.

    Unknown fields are tolerated (a newer firmware may add some) but reported so they are counted.
    """

    message: ArmMessage
    seq: int
    unknown_fields: tuple[str, ...] = ()


# ----------------------------------------------------------------------------- wire envelope


class _Envelope(msgspec.Struct, omit_defaults=True):
    seq: int
    address: int
    funcode: int
    data: dict[str, int | float] | None = None


_encoder = msgspec.json.Encoder()
_decoder = msgspec.json.Decoder(dict[str, Any])

_ENVELOPE_KEYS = frozenset({"seq", "address", "funcode", "data"})
_ANGLE_KEYS = tuple(f"angle{i}" for i in range(JOINT_COUNT))
_MOTOR_KEYS = tuple(f"motor{i}_status" for i in range(JOINT_COUNT))


# The hot path: an angle report, exactly as the spec writes it, decodes straight into typed
# fields (a third of the generic path's cost). Anything else, or anything odd about it (an unknown
# field, a non-finite number, another funcode), takes the generic path, which explains it.
class _AngleData(msgspec.Struct, forbid_unknown_fields=True):
    angle0: float
    angle1: float
    angle2: float
    angle3: float
    angle4: float
    angle5: float
    angle6: float


class _AngleReport(msgspec.Struct, forbid_unknown_fields=True):
    seq: int
    address: int
    funcode: int
    data: _AngleData


_angle_report_decoder = msgspec.json.Decoder(_AngleReport)


def _number(value: float) -> int | float:
    """Integral values are written as integers, as the spec's examples do."""
    if isinstance(value, int):
        return int(value)  # (bool -> 0/1; math.isfinite overflows on a huge int)
    if not math.isfinite(value):
        raise InvalidCommand(f"non-finite number {value!r} cannot be sent to the arm")
    return int(value) if float(value).is_integer() else float(value)


def _flag(value: bool) -> int:
    return 1 if value else 0


def _error_status(value: int) -> int:
    low, high = ERROR_STATUS_RANGE
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise InvalidCommand(f"error_status {value!r} is not a 64-bit integer")
    return value


# ----------------------------------------------------------------------------- validation


def check_joint(joint: int) -> None:
    """Raise InvalidCommand unless ``joint`` is a wire joint id 0..6."""
    if isinstance(joint, bool) or not isinstance(joint, int) or not 0 <= joint < JOINT_COUNT:
        raise InvalidJoint(f"joint id {joint!r} is out of range; the D1 has joints 0..6")


def check_angle(joint: int, angle_deg: float, ranges: JointRanges = JOINT_RANGE_DEG) -> None:
    """Raise InvalidCommand unless ``angle_deg`` is finite and inside joint ``joint``'s range
    (``ranges``: the arm's, whose gripper may read another way, ``limits.joint_ranges``)."""
    check_joint(joint)
    if not isinstance(angle_deg, (int, float)) or isinstance(angle_deg, bool):
        raise InvalidCommand(f"joint {joint}: angle {angle_deg!r} is not a number")
    low, high = ranges[joint]
    try:
        value = float(angle_deg)
    except OverflowError:  # an int too large for a float
        raise InvalidCommand(f"joint {joint}: angle is far outside its range") from None
    if not math.isfinite(value):
        raise InvalidCommand(f"joint {joint}: angle {angle_deg!r} is not finite")
    if not low <= value <= high:
        raise InvalidCommand(
            f"joint {joint}: angle {value:g} deg is outside its range [{low:g}, {high:g}] deg"
        )


def validate_command(command: Command, ranges: JointRanges = JOINT_RANGE_DEG) -> None:
    """Raise InvalidCommand if ``command`` must not reach an arm with joint ``ranges``."""
    if isinstance(command, SetJointAngle):
        check_angle(command.joint, command.angle_deg, ranges)
        if command.delay_ms < 0:
            raise InvalidCommand(f"delay_ms {command.delay_ms} is negative")
    elif isinstance(command, SetAllAngles):
        if len(command.angles_deg) != JOINT_COUNT:
            raise InvalidCommand(
                f"expected {JOINT_COUNT} angles (joints 0..6), got {len(command.angles_deg)}"
            )
        for joint, angle in enumerate(command.angles_deg):
            check_angle(joint, angle, ranges)
        if command.mode not in (0, 1):
            raise InvalidCommand(f"mode {command.mode!r} is not 0 (small) or 1 (large smoothing)")
    elif isinstance(command, SetJointTorque):
        check_joint(command.joint)
    elif isinstance(command, SetAllTorque):
        if isinstance(command.mode, bool) or not 0 <= command.mode <= TORQUE_MODE_MAX:
            raise InvalidCommand(f"torque mode {command.mode!r} is outside 0..{TORQUE_MODE_MAX}")
    elif not isinstance(command, (SetPower, ReturnToZero)):
        raise InvalidCommand(f"{type(command).__name__} is not a D1 command")


def check_seq(seq: int) -> None:
    """Raise InvalidCommand for a seq the caller may not use (10 is the arm's own)."""
    if isinstance(seq, bool) or not isinstance(seq, int) or seq < 0:
        raise InvalidCommand(f"seq {seq!r} must be a non-negative integer")
    if seq == ARM_REPORT_SEQ:
        raise InvalidCommand("seq 10 is reserved for the arm's own reports")


# ----------------------------------------------------------------------------- encode


def _command_data(command: Command) -> dict[str, int | float] | None:
    if isinstance(command, SetJointAngle):
        return {
            "id": command.joint,
            "angle": _number(command.angle_deg),
            "delay_ms": command.delay_ms,
        }
    if isinstance(command, SetAllAngles):
        data: dict[str, int | float] = {"mode": command.mode}
        for key, angle in zip(_ANGLE_KEYS, command.angles_deg, strict=False):
            data[key] = _number(angle)
        return data
    if isinstance(command, SetJointTorque):
        return {"id": command.joint, "mode": _flag(command.enable)}
    if isinstance(command, SetAllTorque):
        return {"mode": command.mode}
    if isinstance(command, SetPower):
        return {"power": _flag(command.on)}
    return None


def encode_command(command: Command, seq: int, ranges: JointRanges = JOINT_RANGE_DEG) -> str:
    """The JSON text to write on ``rt/arm_Command<suffix>``; validates first (``ranges``: the
    arm's joint ranges)."""
    check_seq(seq)
    validate_command(command, ranges)
    envelope = _Envelope(seq, COMMAND_ADDRESS, _FUNCODE_OF[type(command)], _command_data(command))
    return _encoder.encode(envelope).decode()


def encode_message(message: ArmMessage, seq: int = ARM_REPORT_SEQ) -> str:
    """The JSON text the arm writes on ``rt/arm_Feedback<suffix>`` (used by the simulator).

    Reports always carry seq 10; acknowledgments carry the seq of the command they answer.
    """
    data: dict[str, int | float]
    if isinstance(message, JointAngles):
        if len(message.angles_deg) != JOINT_COUNT:
            raise InvalidCommand(f"expected {JOINT_COUNT} angles, got {len(message.angles_deg)}")
        data = {k: _number(a) for k, a in zip(_ANGLE_KEYS, message.angles_deg, strict=False)}
        address, funcode = REPORT_ADDRESS, 1
    elif isinstance(message, D1Status):
        data = {
            "enable_status": _flag(message.enabled),
            "power_status": _flag(message.powered),
            "error_status": _error_status(message.error_status),
        }
        address, funcode = REPORT_ADDRESS, 3
    elif isinstance(message, MotorStatus):
        if len(message.motors_ok) != JOINT_COUNT:
            raise InvalidCommand(f"expected {JOINT_COUNT} motors, got {len(message.motors_ok)}")
        data = {k: _flag(ok) for k, ok in zip(_MOTOR_KEYS, message.motors_ok, strict=False)}
        address, funcode = REPORT_ADDRESS, 4
    elif isinstance(message, ReceiveAck):
        data, address, funcode, seq = (
            {"recv_status": _flag(message.ok)},
            ACK_ADDRESS,
            1,
            message.seq,
        )
    elif isinstance(message, ExecuteAck):
        data, address, funcode, seq = (
            {"exec_status": _flag(message.ok)},
            ACK_ADDRESS,
            2,
            message.seq,
        )
    else:
        raise InvalidCommand(f"{type(message).__name__} is not a D1 arm message")
    return _encoder.encode(_Envelope(seq, address, funcode, data)).decode()


# ----------------------------------------------------------------------------- decode


def _parse_envelope(text: str | bytes) -> tuple[int, int, int, dict[str, Any], list[str]]:
    if len(text) > MAX_MESSAGE_BYTES:
        raise MalformedMessage(f"{len(text)} bytes is over the {MAX_MESSAGE_BYTES} byte limit")
    try:
        raw = _decoder.decode(text)
    except msgspec.DecodeError as exc:
        # msgspec refuses NaN/Infinity literals and numbers that overflow to infinity.
        raise MalformedMessage(f"not valid JSON: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - msgspec raises RecursionError (JSON nested ~1000
        # deep) and UnicodeDecodeError (invalid UTF-8) too: whoever writes on the arm's topics
        # must not be able to kill the thread that reads them.
        raise MalformedMessage(f"not valid JSON: {type(exc).__name__}: {exc}") from None
    unknown = sorted(k for k in raw if k not in _ENVELOPE_KEYS)
    ints = []
    for key in ("seq", "address", "funcode"):
        value = raw.get(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise MalformedMessage(f"field {key!r} is missing or not an integer: {value!r}")
        ints.append(value)
    data = raw.get("data", {})
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise MalformedMessage(f"field 'data' is not an object: {data!r}")
    return ints[0], ints[1], ints[2], data, unknown


def _read_number(data: dict[str, Any], key: str) -> float:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MalformedMessage(f"data.{key} is missing or not a number: {value!r}")
    try:
        number = float(value)
    except OverflowError:
        # msgspec decodes a 400-digit integer to an int that no float can hold.
        raise MalformedMessage(f"data.{key} is an integer too large for a number") from None
    if not math.isfinite(number):
        raise MalformedMessage(f"data.{key} is not finite: {value!r}")
    return number


def _read_int(data: dict[str, Any], key: str) -> int:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        # The arm writes integers; 1.0 is tolerated because some JSON writers emit it.
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise MalformedMessage(f"data.{key} is missing or not an integer: {value!r}")
    return value


def _read_flag(data: dict[str, Any], key: str) -> bool:
    value = _read_int(data, key)
    if value not in (0, 1):
        raise MalformedMessage(f"data.{key} must be 0 or 1, got {value}")
    return value == 1


def _read_error_status(data: dict[str, Any]) -> int:
    """Any integer: 1 normal, anything else abnormal (0 per the table, a bitfield per the
    contact plan); the raw value is kept for the status and the log."""
    value = _read_int(data, "error_status")
    low, high = ERROR_STATUS_RANGE
    if not low <= value <= high:
        raise MalformedMessage(f"data.error_status {str(value)[:40]} is not a 64-bit integer")
    return value


def _unknown_data(data: dict[str, Any], known: tuple[str, ...]) -> list[str]:
    return [f"data.{k}" for k in data if k not in known]


def _decode_angle_report(text: str | bytes) -> Decoded | None:
    """A well-formed angle report, or None (then the generic path decides)."""
    if len(text) > MAX_MESSAGE_BYTES:
        return None
    try:
        report = _angle_report_decoder.decode(text)
    except Exception:  # noqa: BLE001 - whatever it is, the generic path names it
        return None
    if (report.address, report.funcode) != (REPORT_ADDRESS, 1):
        return None
    d = report.data
    angles = (d.angle0, d.angle1, d.angle2, d.angle3, d.angle4, d.angle5, d.angle6)
    if not all(map(math.isfinite, angles)):
        return None
    return Decoded(JointAngles(angles), report.seq, ())


def decode_message(text: str | bytes) -> Decoded:
    """Decode one string from ``rt/arm_Feedback<suffix>``.

    Raises MalformedMessage (or its subclass UnknownMessage) for anything that is not a D1 message.
    """
    fast = _decode_angle_report(text)
    if fast is not None:
        return fast
    seq, address, funcode, data, unknown = _parse_envelope(text)
    message: ArmMessage
    if (address, funcode) == (REPORT_ADDRESS, 1):
        known: tuple[str, ...] = _ANGLE_KEYS
        message = JointAngles(tuple(_read_number(data, k) for k in _ANGLE_KEYS))
    elif (address, funcode) == (REPORT_ADDRESS, 3):
        known = ("enable_status", "power_status", "error_status")
        message = D1Status(
            enabled=_read_flag(data, "enable_status"),
            powered=_read_flag(data, "power_status"),
            error_status=_read_error_status(data),
        )
    elif (address, funcode) == (REPORT_ADDRESS, 4):
        known = _MOTOR_KEYS
        message = MotorStatus(tuple(_read_flag(data, k) for k in _MOTOR_KEYS))
    elif (address, funcode) == (ACK_ADDRESS, 1):
        known = ("recv_status",)
        message = ReceiveAck(seq, _read_flag(data, "recv_status"))
    elif (address, funcode) == (ACK_ADDRESS, 2):
        known = ("exec_status",)
        message = ExecuteAck(seq, _read_flag(data, "exec_status"))
    else:
        raise UnknownMessage(address, funcode)
    unknown.extend(_unknown_data(data, known))
    return Decoded(message, seq, tuple(unknown))


def decode_command(text: str | bytes, ranges: JointRanges = JOINT_RANGE_DEG) -> tuple[int, Command]:
    """Decode one string from ``rt/arm_Command<suffix>`` into (seq, command).

    This is what the arm's service does; the simulator uses it. Out-of-range values raise
    InvalidCommand (the arm answers recv_status 0), malformed text MalformedMessage.
    """
    seq, address, funcode, data, _unknown = _parse_envelope(text)
    try:
        command = _command_from(address, funcode, data)
        validate_command(command, ranges)
    except (InvalidCommand, MalformedMessage) as exc:
        exc.seq = seq
        raise
    return seq, command


def _command_from(address: int, funcode: int, data: dict[str, Any]) -> Command:
    if address != COMMAND_ADDRESS:
        raise UnknownMessage(address, funcode)
    command: Command
    if funcode == 1:
        command = SetJointAngle(
            joint=_read_int(data, "id"),
            angle_deg=_read_number(data, "angle"),
            delay_ms=_read_int(data, "delay_ms") if "delay_ms" in data else 0,
        )
    elif funcode == 2:
        mode = _read_int(data, "mode")
        if mode not in (0, 1):
            raise InvalidCommand(f"mode {mode} is not 0 or 1")
        angles = tuple(_read_number(data, k) for k in _ANGLE_KEYS)
        command = SetAllAngles(angles_deg=angles, mode=0 if mode == 0 else 1)
    elif funcode == 4:
        command = SetJointTorque(joint=_read_int(data, "id"), enable=_read_flag(data, "mode"))
    elif funcode == 5:
        command = SetAllTorque(mode=_read_int(data, "mode"))
    elif funcode == 6:
        command = SetPower(on=_read_flag(data, "power"))
    elif funcode == 7:
        command = ReturnToZero()
    else:
        raise UnknownMessage(address, funcode)
    return command
