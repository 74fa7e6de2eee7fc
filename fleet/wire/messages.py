"""Key-space payloads: the public schema, as msgspec Structs (JSON on the wire).

Units are in the names: ``angles_deg`` (the public key space is in degrees, like the D1 wire),
``stamp_ns`` (wall clock, nanoseconds since the epoch, taken where the data entered the fleet),
``*_s`` seconds, ``*_ms`` milliseconds. ``fleet schema`` prints the JSON Schema of each.
"""

from __future__ import annotations

import enum
from typing import Annotated, Literal

import msgspec
from msgspec import Meta, Struct

LinkState = Literal["ok", "stale", "lost"]
ContactModel = Literal["calibrated", "partial", "uncalibrated", "untrusted"]
"""``partial``: a calibration file that lacks some joints (``fleet calibrate --joint J``)."""

# Bounded numbers: a peer's absurd value (a 400-digit stamp, a lead of 1e300 s) is refused at
# decode time with a path, instead of overflowing later in arithmetic on a worker thread.
StampNs = Annotated[int, Meta(ge=0, le=2**63 - 1)]
"""Wall-clock nanoseconds since the epoch."""
Tolerance = Annotated[float, Meta(gt=0, le=180)]
CommandTimeout = Annotated[float, Meta(gt=0, le=600)]
Lifetime = Annotated[float, Meta(gt=0, le=60)]
Lead = Annotated[float, Meta(ge=0, le=5)]
Period = Annotated[float, Meta(gt=0, le=60)]
Count = Annotated[int, Meta(ge=0, le=2**63 - 1)]
JointId = Annotated[int, Meta(ge=0, le=6)]
Confidence = Annotated[float, Meta(ge=0, le=1)]

# Bounded text and collections: a peer's 1 MB stop id would otherwise be stored, repeated in
# every heartbeat and acknowledged at 10 Hz. Limits are generous for people and small for memory.
Name = Annotated[str, Meta(max_length=128)]
"""Ids and names: ``stop_id``, ``source``, ``owner``, ``coordinator``, arm names."""
Text = Annotated[str, Meta(max_length=1024)]
"""Human text: a stop's reason, an error message, a stop reason."""
Word = Annotated[str, Meta(max_length=32)]
"""A word from a small vocabulary (a stop action, a contact method)."""
Angles = Annotated[list[float], Meta(max_length=7)]
"""One value per D1 joint (wire ids 0..6)."""
Flags = Annotated[list[bool], Meta(max_length=7)]
MAX_STOPS_REPEATED = 4096
"""A heartbeat repeats at most this many latched stops (one per arm, plus the fleet's)."""
MAX_BEAT_COPIES = 16
"""A heartbeat announces at most this many datagram copies of itself."""
MAX_ARMS_REPORTED = 4096
"""The fleet state and a multi-arm reply name at most this many arms."""


class ErrorCode(enum.IntEnum):
    """Command error codes: 3001-3207 mean what Unitree's SDK2 RPC table says (seed 001); the
    fleet's own conditions, which that table has no code for, are 4001-4099. One table of all
    of them, with who returns each: docs/error-codes.md."""

    # Unitree SDK2's codes (3001-3207), with the meaning of its table.
    UNKNOWN = 3001  # unknown error: an unreadable reply
    SEND_FAILED = 3102  # request sending error: the DDS write failed
    NOT_REGISTERED = 3103  # API not registered (client): never returned by the fleet
    TIMEOUT = 3104  # request timeout: no ack from the arm / no answer from the robot in time
    MISMATCH = 3105  # request and response data do not match (a G1 answer to another API)
    INVALID_RESPONSE = 3106  # invalid response data: never returned by the fleet
    CLIENT_LEASE_INVALID = 3107  # never returned by the fleet
    SERVER_SEND_FAILED = 3201  # server side only, never returned
    INTERNAL = 3202  # internal server error
    NOT_IMPLEMENTED = 3203  # API not implemented: unknown "op"
    PARAMETER = 3204  # API parameter error: bad joint id, angle out of range, not finite
    SERVER_REJECTED = 3205  # request rejected *by the robot* (a G1's own answer, passed on)
    LEASE_INVALID = 3206  # invalid lease: release by one who holds none
    LEASE_EXISTS = 3207  # lease already exists: the arm is held by another owner
    # The fleet's own conditions (4001-4099).
    NO_AGENT = 4001  # no agent (or coordinator) answered: is it running?
    REJECTED = 4002  # the fleet refuses in this state: stopped, powered off, no fresh feedback
    BUSY = 4003  # too many commands queued or in flight: retry later
    OUT_OF_ORDER = 4004  # overtaken by a newer command of the same owner (which was taken)
    EXPIRED = 4005  # reached the agent past its lifetime: not executed
    NOT_REACHED = 4006  # wait_reached: the target was not reached within timeout_s
    ARM_REFUSED = 4007  # the arm answered recv_status 0 (could not parse or take it)
    ARM_FAILED = 4008  # the arm answered exec_status 0 (it did not execute it)


OVERTAKEN = "out of order"
"""How an agent's refusal of a command overtaken by a newer one of the same owner begins (code
4004, ``OUT_OF_ORDER``): the newer one was accepted, so a stream of targets loses nothing by
it."""


class ErrorInfo(Struct, frozen=True):
    """Why a command failed: ``code`` from ErrorCode, ``message`` for humans."""

    code: Annotated[int, Meta(ge=0, le=99999)]
    message: Text


class Joints(Struct, frozen=True):
    """``arm/<arm>/joints``: measured angles (degrees, wire ids 0..6). ``seq`` counts the
    samples the agent relayed for this arm (the arm's own seq is always 10)."""

    stamp_ns: StampNs
    angles_deg: Angles
    seq: Count


class ArmStatus(Struct, frozen=True):
    """``arm/<arm>/status``: the arm's state as its agent sees it. ``None`` = not reported yet."""

    stamp_ns: StampNs
    link: LinkState
    enabled: bool | None = None
    powered: bool | None = None
    error: bool | None = None
    motors_ok: Flags | None = None
    estopped: bool = False
    feedback_age_s: float | None = None
    stop_reason: Text | None = None
    owner: Text | None = None
    """Who holds the arm's lease (``<principal>/<name>``: longer than a Name), None: nobody."""
    owned_s: float | None = None
    """How long ``owner`` has held the arm, in seconds."""
    lease_left_s: float | None = None
    """Seconds until the lease expires unless its owner commands again."""
    error_status: int | None = None
    """The arm's raw ``error_status`` (1 normal; 0 or any other value, perhaps a bitfield of
    fault flags, abnormal: then ``error`` is true)."""
    contact_model: ContactModel | None = None
    """The contact detector's model of this arm: ``uncalibrated`` (run ``fleet calibrate``),
    ``calibrated``, or ``untrusted`` (calibrated, but found off in free motion: see diag);
    None with contact detection disabled."""
    watched_by: Text | None = None
    """The commander whose heartbeat the arm's watchdog watches now (``<principal>/<name>``;
    None: none). Its coordinator sends its beats' datagram copies while some unit watches it."""


class Diag(Struct, frozen=True):
    """``arm/<arm>/diag``: the agent's counters for this arm (monotonic since agent start)."""

    stamp_ns: StampNs
    link: LinkState
    relayed: Count
    malformed: Count
    unknown_messages: Count
    unknown_fields: Count
    rejected: Count
    commands: Count
    ack_timeouts: Count
    feedback_rate_hz: float
    last_feedback_age_s: float | None
    last_error: Text | None = None
    # The agent's own counters (the same in the diag of every arm it serves):
    bad_payloads: Count = 0
    """Stop, reset, heartbeat and command payloads that did not decode (too large, malformed)."""
    undecodable_stops: Count = 0
    """Of those, stops: each still stopped the arms (anyone may stop)."""
    busy: Count = 0
    """Commands answered 3205 "busy" at once because the agent's command queue was full."""
    bad_keys: Count = 0
    """Command queries on a key whose last chunk names no usable principal (``cmd/bob.smith``,
    ``cmd/*``): each answered 2001 and served no further; and heartbeats on such a key
    (``heartbeat/bob.smith``: ignored)."""
    latch_failures: Count = 0
    """Latched stops (or their removal at a reset) the agent could not write to disk (a full
    disk, a refused symbolic link); while a unit's latest is unwritten its ``stop_reason``
    says so."""
    dropped_events: Count = 0
    """Resets and heartbeat sources dropped at a full queue (a flood); stops are never dropped."""
    bad_stamps: Count = 0
    """Stops and resets stamped more than 2 s ahead of the agent's clock (a wrong clock, or a
    forgery): such a stop latched all the same, such a reset was refused."""
    write_failures: Count = 0
    """DDS writes that failed (maybe sent)."""
    stop_copies_reliable: Count = 0
    """Stop requests received over the reliable path (every copy and repeat, before the
    de-duplication by ``stop_id``)."""
    stop_copies_datagram: Count = 0
    """The same over the datagram path (0 with none: ``fleet/wire/stoppath.py``)."""
    beat_copies_reliable: Count = 0
    """Heartbeats received over the reliable path (before any check)."""
    beat_copies_datagram: Count = 0
    """The same over the datagram path."""
    datagram_replaced: Count = 0
    """Times the agent's datagram session was replaced (its link re-made, or deaf)."""
    foreign_feedback: Count = 0
    """Valid-looking feedback the arm did not send (dropped): from a writer on another host,
    or a second writer of a periodic report on the arm's host."""
    implausible_feedback: Count = 0
    """Angle reports implying an impossible speed (dropped: a sensor fault or a forgery)."""
    acks_unmatched: Count = 0
    """Acks with seq 10 (an arm answering as the spec's examples do): credited to the arm's
    oldest command awaiting that kind of ack."""
    acks_foreign: Count = 0
    """Acks whose seq is neither a command we wrote lately nor 10 (another client commanding
    the arm, or garbage): credited to no command."""
    acks_ignored: Count = 0
    """Acks credited to no command: late (after the ack timeout) or repeated, or none awaited."""
    contact_model: Text | None = None
    """What the contact detector's model of this arm is worth (uncalibrated, calibrated, or
    why it stopped trusting it), and the calibration file's problem if it has one."""
    contact_free_moves: Count = 0
    """Moves that ended in free motion since the calibration was loaded (online sanity)."""
    contact_model_error_deg: float | None = None
    """How far the joint lagged the model during the latest of them (degrees)."""


# ----------------------------------------------------------------------------- commands


class _CommandBase(Struct, tag_field="op", kw_only=True, forbid_unknown_fields=True):
    """Options every command accepts.

    ``wait_reached``: also wait until feedback shows the target reached (within
    ``tolerance_deg``, at most ``timeout_s``); the arm's own acks are known to be unreliable.
    ``owner``: who commands (a lease: others are refused with 3207 until it expires), and
    ``takeover`` to take the arm from its current owner. ``start_at_ns``: wall-clock time at
    which the agent writes the command (synchronized multi-arm starts); at most 5 s ahead.
    ``stamp_ns`` + ``lifetime_s``: a streamed target sent at ``stamp_ns`` is refused (3104) if
    it reaches the agent more than ``lifetime_s`` later: a late target is never executed.
    """

    wait_reached: bool = False
    tolerance_deg: Tolerance = 2.0
    timeout_s: CommandTimeout = 10.0
    owner: Name | None = None
    takeover: bool = False
    start_at_ns: StampNs | None = None
    stamp_ns: StampNs | None = None
    lifetime_s: Lifetime | None = None


class MoveJoint(_CommandBase, tag="move_joint", kw_only=True):
    """Move one joint (wire id 0..6) to ``angle_deg``."""

    joint: JointId
    angle_deg: float


class MoveJoints(_CommandBase, tag="move_joints", kw_only=True):
    """Move all seven joints; ``mode`` 0 = small smoothing (streaming), 1 = large smoothing."""

    angles_deg: Angles
    mode: Literal[0, 1] = 1


class Torque(_CommandBase, tag="torque", kw_only=True):
    """Enable (``on``) or unload one joint, or all joints when ``joint`` is null.
    ``strength`` (all joints only) is the spec's 0..80000 holding strength."""

    on: bool
    joint: JointId | None = None
    strength: Annotated[int, Meta(ge=0, le=80000)] | None = None


class Power(_CommandBase, tag="power", kw_only=True):
    """Switch the motors' power supply."""

    on: bool


class Zero(_CommandBase, tag="zero", kw_only=True):
    """Return every joint to zero."""


class Hold(_CommandBase, tag="hold", kw_only=True):
    """Make the measured angles the target: the arm stays where it is."""


class Release(_CommandBase, tag="release", kw_only=True):
    """``owner`` gives up its lease on the arm (nothing is sent to the arm)."""


ArmCommand = MoveJoint | MoveJoints | Torque | Power | Zero | Hold | Release
MOTION_OPS = (MoveJoint, MoveJoints, Zero)
COMMAND_OPS = frozenset(
    str(kind.__struct_config__.tag) for kind in (MoveJoint, MoveJoints, Torque, Power, Zero)
) | {"hold", "release"}
"""Every ``op`` an agent serves (another one is answered 3203, not implemented)."""


class CommandReply(Struct, frozen=True):
    """The reply of ``arm/<arm>/cmd``.

    ``received``/``executed`` are the arm's receive and execute acks (``executed`` null when it
    was not awaited); ``reached`` is null unless ``wait_reached`` was asked.
    """

    ok: bool
    arm: Name
    seq: Annotated[int, Meta(ge=0, le=65535)] | None
    received: bool
    executed: bool | None
    reached: bool | None
    latency_ms: float
    error: ErrorInfo | None = None
    written_ns: StampNs | None = None


class DeviceCommand(Struct, tag_field="op", kw_only=True, forbid_unknown_fields=True):
    """The envelope every device command carries, as the arm's do: ``owner`` (a lease: others
    are refused 3207 until it expires) and ``takeover``; ``stamp_ns`` (the sender's clock,
    increasing per client: duplicates and out-of-order commands are refused) and
    ``lifetime_s`` (a command arriving later than that is refused, never executed)."""

    owner: Name | None = None
    takeover: bool = False
    stamp_ns: StampNs | None = None
    lifetime_s: Lifetime | None = None


class DeviceRelease(DeviceCommand, tag="release", kw_only=True):
    """Give the device up (ends ``owner``'s lease and its watchdog watch); nothing is written."""


class DeviceReply(Struct, frozen=True):
    """The reply to a device command (``<kind>/<device>/cmd/<principal>``): ``ok``, the device,
    what was written (``written``: a short text of the DDS message) and the error, if any, with
    the arm's error codes (``fleet.wire.messages.ErrorCode``)."""

    ok: bool
    device: Annotated[str, Meta(max_length=128)]
    error: ErrorInfo | None = None
    written_ns: Annotated[int, Meta(ge=0, le=2**63 - 1)] | None = None
    result: Annotated[str, Meta(max_length=1024)] | None = None
    """A query's answer (``get_fsm_id``: the id), as text."""


# ----------------------------------------------------------------------------- protective stop


class StopRequest(Struct, frozen=True):
    """Put on ``fleet/<fleet>/estop`` (every arm) or ``arm/<arm>/estop`` (one arm).

    ``stop_id`` identifies one stop so agents can acknowledge it and ignore its repeats;
    ``source`` says who pressed it (``cli@host``, ``viewer``, ``coordinator``, ...).
    """

    stamp_ns: StampNs
    source: Name
    stop_id: Name
    reason: Text = ""


class ResetRequest(Struct, frozen=True):
    """Put on ``fleet/<fleet>/reset`` or ``arm/<arm>/reset``: an operator releases the latch.

    A reset never moves an arm: the agent makes the measured pose the target.
    """

    stamp_ns: StampNs
    source: Name
    reset_id: Name | None = None
    """Names this reset in the ``reset/ack`` of each unit it reached (None: the sender waits
    for no answer)."""


ResetOutcome = Literal["released", "not_stopped", "kept", "refused"]


class ResetAck(Struct, frozen=True):
    """``arm/<arm>/reset/ack`` (``<kind>/<id>/reset/ack``): what a reset did to one unit.

    ``released``: its stop is released; ``not_stopped``: nothing was latched; ``kept``: a stop
    put after the reset is latched (reset again); ``refused``: the reset's stamp is far ahead
    of the agent's clock. ``detail`` says it in words, for the operator."""

    unit: Name
    reset_id: Name
    outcome: ResetOutcome
    detail: Text = ""
    received_ns: StampNs = 0


class StopAck(Struct, frozen=True):
    """``arm/<arm>/estop/ack``: what the agent did about a stop, with its times (wall clock, ns).

    Published when the stop was received and acted on, and again when feedback showed the arm
    still, so the fan-out is measurable per arm. ``still_ns``: when the arm was still, the first
    of the reports that confirm it (the ack is published with the last of them).
    """

    arm: Name
    stop_id: Name
    action: Word
    received_ns: StampNs
    dds_written_ns: StampNs | None
    still_ns: StampNs | None = None
    detail: Text | None = None
    confirmed_ns: StampNs | None = None
    """``unload``/``power_off`` stops: when the arm's status showed it unloaded / unpowered."""

    @property
    def done(self) -> bool:
        """Confirmed by feedback: still, and unloaded / unpowered for those actions."""
        return self.still_ns is not None and (
            self.action == "hold" or self.confirmed_ns is not None
        )


class Heartbeat(Struct, frozen=True):
    """``fleet/<fleet>/heartbeat``: the coordinator is alive (default 10 Hz).

    ``stops`` repeats every latched stop (key: arm id, or ``*`` for the whole fleet), so an
    agent that missed a stop, joined late or reconnected learns it within one period.
    """

    stamp_ns: StampNs
    coordinator: Name
    seq: Count
    period_s: Period
    stops: Annotated[dict[Name, StopRequest], Meta(max_length=MAX_STOPS_REPEATED)] = {}
    datagram_copies: Annotated[int, Meta(ge=0, le=MAX_BEAT_COPIES)] = 2
    """How many copies of this beat follow on the datagram path: 0 while no unit's watchdog
    watches this commander, no stop is latched and it has no datagram session (an agent's deaf
    check then expects none). A beat without it (an older sender) had two."""


# ----------------------------------------------------------------------------- contact

ContactStateName = Literal["free", "suspected", "confirmed", "released"]


class ContactEvent(Struct, frozen=True):
    """``arm/<arm>/contact``: a joint's contact state changed (the agent's detector).

    ``method``: what caused it (``tracking``, ``stall``, ``status``, ``oscillation``,
    ``model``; ``quiet`` for a release, ``not tracking`` when a joint was unloaded).
    ``error_deg``: target minus measured; ``confidence`` 0..1: the share of methods agreeing.
    ``commanded``: the joint was moving under a command (False: it was holding still, so the
    contact came from outside). ``grip``: a confirmed gripper contact while closing.
    ``force_limited``: the agent retracted the joint's target to the measured angle.
    """

    stamp_ns: StampNs
    joint: JointId
    state: ContactStateName
    method: Word
    error_deg: float
    confidence: Confidence
    target_deg: float | None = None
    measured_deg: float | None = None
    commanded: bool = False
    grip: bool = False
    force_limited: bool = False


# ----------------------------------------------------------------------------- coordinator


class ArmSummary(Struct, frozen=True):
    """One arm in the fleet summary. ``online``: its agent's token is present and the agent
    was heard from within ``offline_after_s`` (a partition shows here before Zenoh's lease)."""

    online: bool
    link: LinkState
    enabled: bool | None = None
    powered: bool | None = None
    error: bool | None = None
    estopped: bool = False
    contact: bool | None = None
    feedback_age_s: float | None = None
    heard_age_s: float | None = None


class DeviceSummary(Struct, frozen=True):
    """One device beside the arms in the fleet summary: its kind's key word, online
    as for an arm (its agent's token and its state heard within ``offline_after_s``), its
    state's link and stop, and its kind's one-line summary (``DeviceKind.summary``)."""

    kind: Name
    online: bool
    link: LinkState
    estopped: bool = False
    summary: Annotated[str, Meta(max_length=256)] | None = None
    heard_age_s: float | None = None


class FleetState(Struct, frozen=True):
    """``fleet/<fleet>/state``: the coordinator's summary of every arm and device of the
    inventory. ``devices`` came with the device kinds and defaults to empty: a reader built
    before it ignores it (the Struct takes unknown fields), and a state without it still decodes."""

    stamp_ns: StampNs
    coordinator: Name
    arms: Annotated[dict[Name, ArmSummary], Meta(max_length=MAX_ARMS_REPORTED)]
    devices: Annotated[dict[Name, DeviceSummary], Meta(max_length=MAX_ARMS_REPORTED)] = {}


class CoordinatorDiag(Struct, frozen=True):
    """``fleet/<fleet>/coordinator/diag``: the coordinator's counters (1 Hz, since it started)."""

    stamp_ns: StampNs
    coordinator: Name
    bad_events: Count
    """Samples (status, stop, reset, ack, contact) whose payload did not decode."""
    unknown_arms: Count
    """Samples on the key of an arm that is not in the inventory (ignored)."""
    undecodable_stops: Count
    """Stops that did not decode: the agents stopped on them; the heartbeat does not repeat them."""
    dropped_events: Count
    """Events dropped at a full queue (a flood); stops are never dropped."""
    busy: Count
    """Multi-arm requests answered 3205 "busy" (the queue full, or every worker occupied)."""
    requests_active: Count
    """Multi-arm requests being served now."""
    bad_keys: Count = 0
    """Requests on a key whose last chunk names no usable principal (answered 2001)."""


class MultiArmRequest(Struct, frozen=True, forbid_unknown_fields=True):
    """``fleet/<fleet>/coordinator/cmd`` request: one command for an arm, a group or ``all``.

    With ``sync`` (default) and more than one arm, the coordinator gives every arm the same
    ``start_at_ns``, ``lead_s`` ahead (default: the inventory's ``sync_lead_s``). ``phase``
    tells the contact policy what the motion is for (``lift``: a contact stops the arm)."""

    target: Name
    command: ArmCommand
    sync: bool = True
    lead_s: Lead | None = None
    phase: Literal["approach", "grasp", "lift", "move"] | None = None
    """What the motion is for (contact policy: a contact while ``lift`` stops the arm)."""
    partial: bool = False
    """A synchronized move is all or nothing: unless ``partial``, it is refused (and no arm gets
    a start time) when any target is offline, its link is not ok, or it is stopped."""


class MultiArmReply(Struct, frozen=True):
    """Per arm, what happened; ``start_skew_ms`` is the spread of the arms' DDS write times."""

    ok: bool
    replies: Annotated[dict[Name, CommandReply], Meta(max_length=MAX_ARMS_REPORTED)]
    start_skew_ms: float | None = None
    error: ErrorInfo | None = None


class StopTiming(Struct, frozen=True):
    """Milliseconds from the stop's ``stamp_ns`` to each step on one arm (None: not yet)."""

    received_ms: float | None
    dds_written_ms: float | None
    still_ms: float | None


class StopReport(Struct, frozen=True):
    """``fleet/<fleet>/estop/report``: the coordinator's view of one stop's fan-out."""

    stop_id: Name
    source: Name
    stamp_ns: StampNs
    arms: Annotated[dict[Name, StopTiming], Meta(max_length=MAX_ARMS_REPORTED)]


class ChoreoStatus(Struct, frozen=True):
    """``choreo/<principal>``: a choreography player's state, latest wins: put when it starts
    playing, at each step, every second while it plays, and when it ends (``completed``, or
    ``aborted`` with the ``reason``: what the operator needs to see when a dance stops).
    ``player``: the player's owner id (several may play under one principal); ``iteration``
    and ``step``: where it is (or was when it ended)."""

    stamp_ns: StampNs
    player: Name
    script: Text
    state: Literal["playing", "completed", "aborted"]
    reason: Text = ""
    iteration: Count = 0
    step: Text = ""


class ProcessInfo(Struct, frozen=True):
    """``fleet/<fleet>/info/<role>/<instance>`` (reply): who a long-running process is. ``stamp_ns``
    is its wall clock when it replied (``fleet doctor`` measures clock offsets from it);
    ``metrics_port`` its Prometheus port on 127.0.0.1, if serving."""

    role: Word
    principal: Name
    host: Name
    pid: Count
    version: Word
    started_ns: StampNs
    stamp_ns: StampNs
    arms: Annotated[list[Name], Meta(max_length=MAX_ARMS_REPORTED)] = []
    metrics_port: Annotated[int, Meta(ge=1, le=65535)] | None = None
    datagram: Name | None = None
    """The stops' datagram path (``udp/...`` or ``quic/...?rel=0``) when its session is open;
    None: stops, acks and heartbeats take the reliable path only (or the process has none)."""


# ----------------------------------------------------------------------------- helpers

_encoder = msgspec.json.Encoder()


def encode(message: Struct) -> bytes:
    """JSON bytes of a key-space payload."""
    return _encoder.encode(message)
