"""The agent's side of one G1: ``rt/sportmodestate`` relayed with the FSM named, LocoClient
calls over DDS RPC (checked first: bounds, seed 004's dynamic-state rule, the stop latch),
and the stop action confirmed from sportmodestate. Only the robot's own sportmodestate and
rt/lowstate samples count (``fleet/devices/driver.py``: its host, and on it the first writer of
each topic): a forged state never confirms a stop, allows an FSM-gated call or becomes the pose
the arms' stream starts from; other writers' samples are counted (``foreign``) and dropped.

Threads as for every device (``fleet/devices/driver.py``). RPC: one long-lived request writer
and response reader; each call gets a fresh request id, and its answer is matched by that id
on the relay thread, which replies (no thread waits for the robot: a call unanswered within
``rpc_timeout_s`` is answered 3104 by ``tick``). The core's write lock of the device
serializes requests with the stop's own: nothing checked before a stop is written after it.

Firmware readings, in marked blocks: the service name per device
(``fleet/g1/probe.py``: ``sport``, ``loco`` or ``auto``; one request writer and response reader
per candidate name, GetFsmId asked from ``tick`` until answered); the stop action's calls from
``loco.stop_calls`` (``stop_move`` also ends continuous gait), to every candidate name while
``auto`` has not found it.

The waist and arms (``rt/lowstate``, the ``rt/arm_sdk`` stream) are ``fleet/g1/arm_link.py``'s,
on this driver's lock; the stop action is written first and the arms handled beside it.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from dataclasses import dataclass
from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from fleet.devices.base import DeviceReply, Release
from fleet.devices.driver import Done, DriverBase, LatchView, Put, error_reply
from fleet.g1 import arms, idl, loco
from fleet.g1.arm_link import STATE_READER_QOS, ArmLink
from fleet.g1.config import G1Config
from fleet.g1.messages import (
    OPS,
    READS,
    ArmRelease,
    ArmTarget,
    BalanceStand,
    ContinuousGait,
    Damp,
    G1LowState,
    G1State,
    Move,
    SetFsmId,
    SetSpeedMode,
    SetStandHeight,
    SetTaskId,
    SetVelocity,
    ShakeHand,
    StopMove,
    WaveHand,
)
from fleet.g1.probe import ServiceProbe
from fleet.origin.directory import WriterDirectory
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.payloads import G1_COMMAND

log = logging.getLogger("edge_agent.g1")

COMMAND = G1_COMMAND
RPC_QOS = Qos(
    Policy.Reliability.Reliable(duration(milliseconds=100)),
    Policy.History.KeepLast(16),
    Policy.Durability.Volatile,
)
CONFIRM_SAMPLES = 3
"""The stop is confirmed by this many consecutive sportmodestate samples after its write."""
MAX_PENDING = 16
TICK_MAX_S = 0.05
"""Ticks at least this often: the stop action's repeat and the link's staleness."""


@dataclass
class _Pending:
    """A call awaiting the robot's answer."""

    op: str
    api_id: int
    written_ns: int
    deadline_s: float
    done: Done


class G1Driver(DriverBase):
    """One G1 served by the agent core (create on the core's start-up thread)."""

    commands = COMMAND

    def __init__(
        self,
        config: G1Config,
        participant: Any,
        directory: WriterDirectory,
        put: Put,
        latch: LatchView,
    ) -> None:
        counters = ("rpc_calls", "unmatched")
        super().__init__(config.id, put, latch, counters, config.link_stale_s, directory)
        self.config = config
        self.stop_action = config.stop_action
        state = Topic(participant, loco.STATE_TOPIC, idl.SportModeState_)
        self._state_reader = DataReader(participant, state, qos=STATE_READER_QOS)
        self.readers = [self._state_reader]
        # one request writer and response reader per candidate service name.
        self._probe = ServiceProbe(config.service)
        self._services = self._probe.candidates
        self._writers: dict[str, DataWriter] = {}
        for service in self._services:
            request = Topic(participant, loco.request_topic(service), idl.Request_)
            response = Topic(participant, loco.response_topic(service), idl.Response_)
            self.readers.append(DataReader(participant, response, qos=RPC_QOS))
            self._writers[service] = DataWriter(participant, request, qos=RPC_QOS)
        # rt/lowstate and the waist and arms' rt/arm_sdk (``fleet/g1/arm_link.py``).
        self._arms = ArmLink(config, participant, self._lock, self._own)
        self._low_index = len(self.readers)
        self.readers += [self._arms.lowstate_reader, self._arms.arm_sdk_reader]
        self._probe_ids: dict[int, str] = {}
        # Request ids this driver's answers are matched by: from the clock at creation, so
        # two processes (an agent and a Unitree SDK client) asking the same robot differ.
        self._ids = itertools.count(time.time_ns())
        self._stop_detail: str | None = None
        self._latest: tuple[idl.SportModeState_, float] | None = None
        self._changed = False
        self._next_put_s = 0.0
        self._confirming = 0
        self._pending: dict[int, _Pending] = {}
        self._limits = (config.max_vx, config.max_vy, config.max_omega, config.max_duration_s)

    # ------------------------------------------------------------------ relay thread

    def on_data(self, index: int, now_s: float) -> None:
        """State samples (newest kept; stop confirmation), rt/lowstate (each checked, the
        newest good one kept), rt/arm_sdk of other writers, or RPC responses (matched by id)."""
        if index == self._low_index:
            bad = self._arms.on_lowstate(now_s)
            with self._lock:
                self._counts["bad_samples"] += bad
            return
        if index == self._low_index + 1:
            if self._arms.on_arm_sdk():
                with self._lock:
                    self._changed = True
            return
        if index >= 1:
            self._on_responses(index)
            return
        for sample in self._state_reader.take(N=64):
            if not isinstance(sample, idl.SportModeState_) or not math.isfinite(sample.task_time):
                with self._lock:
                    self._counts["bad_samples"] += int(hasattr(sample, "__idl_typename__"))
                continue
            if not self._own(self._state_reader, sample, loco.STATE_TOPIC, now_s):
                continue
            with self._lock:
                self._counts["dds_samples"] += 1
                old = self._latest[0] if self._latest is not None else None
                if old is None or (old.fsm_id, old.fsm_mode) != (sample.fsm_id, sample.fsm_mode):
                    self._changed = True
                self._latest = (sample, now_s)
                if self._stop_written_s is not None and now_s > self._stop_written_s:
                    self._confirming = self._confirming + 1 if self._stopped(sample) else 0

    def _own(self, reader: DataReader, sample: Any, topic: str, now_s: float) -> bool:
        """``sample`` (a valid one, from ``reader.take`` on ``topic``) is the robot's own."""
        handle = int(sample.sample_info.publication_handle)
        return self._from_the_device(reader, handle, topic, now_s)

    def _stopped(self, sample: idl.SportModeState_) -> bool:
        if self.stop_action == "damp":
            return bool(sample.fsm_id == loco.DAMP_FSM)
        return bool(sample.fsm_mode == loco.STATIC)

    def _on_responses(self, index: int) -> None:
        service = self._services[index - 1]
        answered: list[tuple[_Pending, idl.Response_]] = []
        for response in self.readers[index].take(N=64):
            if not isinstance(response, idl.Response_):
                continue
            with self._lock:
                if self._probe_ids.pop(response.header.identity.id, None) is not None:
                    # the topic it came on names the service that answered.
                    if self._probe.answer(service):
                        log.info("%s: the LocoClient service is %r", self.device, service)
                    self._changed = True
                    continue
                call = self._pending.pop(response.header.identity.id, None)
                if call is None:
                    self._counts["unmatched"] += 1  # another client's, or a late answer
                    continue
            answered.append((call, response))
        for call, response in answered:
            call.done(self._answer(call, response))

    def _answer(self, call: _Pending, response: idl.Response_) -> DeviceReply:
        code = int(response.header.status.code)
        if response.header.identity.api_id != call.api_id:
            code = m.ErrorCode.MISMATCH  # request and response do not match (seed 001)
        if code != 0:
            return DeviceReply(
                ok=False,
                device=self.device,
                error=m.ErrorInfo(
                    code, f"g1 {self.device!r}: the robot answered {code} to {call.op}"
                ),
                written_ns=call.written_ns,
            )
        result = None
        if call.op in ("get_fsm_id", "get_fsm_mode", "get_balance_mode"):
            value = loco.parse_data(response.data)
            result = None if value is None else str(value)
        return DeviceReply(ok=True, device=self.device, written_ns=call.written_ns, result=result)

    def tick(self, now_s: float) -> float:
        """The state on change and at the relay rate; calls past their timeout answered 3104.
        Returns when the next tick is due."""
        with self._lock:
            self._update_rate(now_s)
            due = self._changed or now_s >= self._next_put_s
            state = self._state(now_s) if due else None
            if due:
                self._changed = False
                self._next_put_s = now_s + 1.0 / self.config.relay_hz
                self._counts["relayed"] += 1
            expired = [i for i, c in self._pending.items() if c.deadline_s <= now_s]
            late = [self._pending.pop(i) for i in expired]
            self._counts["timeouts"] += len(late)
            next_s = min(self._next_put_s, now_s + TICK_MAX_S)
            ask = self._probe.due(now_s)
            latest = self._latest
        low = self._lowstate(now_s) if due else None
        if self._arms.step(now_s, latest):
            with self._lock:
                self._changed = True
        arm_due = self._arms.next_due()
        if arm_due is not None:
            next_s = min(next_s, arm_due)
        if state is not None:
            self._put(keys.STATE, m.encode(state), False)
        if low is not None:
            self._put(keys.LOWSTATE, m.encode(low), False)
        if ask:
            self._ask_service(ask)
        for call in late:
            why = (
                f"g1 {self.device!r}: no answer to {call.op} within {self.config.rpc_timeout_s:g} s"
            )
            call.done(error_reply(self.device, m.ErrorCode.TIMEOUT, why))
        return next_s

    def _ask_service(self, services: tuple[str, ...]) -> None:
        """GetFsmId on each candidate name; the first answer names the service. (Not
        under the core's write lock: a read, ordered against nothing.)"""
        call = loco.call_for("get_fsm_id")
        for service in services:
            request_id = self._send(call, None, service)
            with self._lock:
                self._probe_ids[request_id] = service
                while len(self._probe_ids) > MAX_PENDING:  # unanswered asks: the oldest go
                    self._probe_ids.pop(next(iter(self._probe_ids)))

    def _state(self, now_s: float) -> G1State | None:
        if self._latest is None:
            return None
        sample, at_s = self._latest
        mode = {0: "static", 1: "dynamic"}.get(sample.fsm_mode, "unknown")
        latched, reason, watched_by = self._latch()
        stream = self._arms.stream
        return G1State(
            stamp_ns=time.time_ns(),
            fsm_id=sample.fsm_id,
            fsm_name=loco.fsm_name(sample.fsm_id),
            fsm_mode=sample.fsm_mode,
            mode=mode,  # type: ignore[arg-type]
            task_id=sample.task_id,
            task_time=round(float(sample.task_time), 3),
            link="stale" if now_s - at_s > self.config.link_stale_s else "ok",
            estopped=latched,
            stop_reason=reason,
            stop_action=self.stop_action,
            dds_samples=self._counts["dds_samples"],
            bad_samples=self._counts["bad_samples"],
            dds_rate_hz=round(self._rate_hz, 1),
            service=self._probe.service,
            service_setting=self.config.service,
            service_answered=self._probe.service in self._probe.answered,
            stop_detail=self._stop_detail if latched else None,
            arm_phase=stream.phase,
            arm_weight=None if stream.weight is None else round(stream.weight, 3),
            arm_released=stream.why_released,
            arm_held=stream.why_held,
            watched_by=watched_by,
        )

    # ------------------------------------------------------------------ the waist and arms

    def _lowstate(self, now_s: float) -> G1LowState | None:
        checked = self._arms.newest(now_s)
        with self._lock:
            bad = self._counts["bad_samples"]
        if checked is None:
            return None
        q, imu = checked[1], checked[0].imu_state
        return G1LowState(
            stamp_ns=time.time_ns(),
            q_rad=[round(v, 4) for v in q],
            imu_rpy=[round(float(v), 4) for v in imu.rpy],
            imu_quaternion=[round(float(v), 5) for v in imu.quaternion],
            tick=int(checked[0].tick),
            bad_samples=bad,
        )

    def _arm_command(self, command: ArmTarget | ArmRelease, now_s: float) -> DeviceReply:
        """A target (checked: seed 004's FSM states, limits, speed, distance from the measured
        pose) starts or steers the stream; a release ramps it down."""
        if isinstance(command, ArmRelease):
            changed, result = self._arms.release("released by its owner", now_s)
            with self._lock:
                self._changed |= changed
            return DeviceReply(ok=True, device=self.device, result=result)
        state = self._fresh_state(now_s)
        if state is None:
            raise self._refuse(
                m.ErrorCode.REJECTED,
                f"g1 {self.device!r}: no fresh {loco.STATE_TOPIC}: the FSM is unknown",
            )
        if state.fsm_id not in loco.ARM_SDK_FSMS:
            raise self._refuse(
                m.ErrorCode.REJECTED,
                f"g1 {self.device!r}: rt/arm_sdk is allowed only in lock standing (4) and the "
                f"walking controller (500, 501) (seed 004), and it is in fsm {state.fsm_id} "
                f"{loco.fsm_name(state.fsm_id)}: send start first",
            )
        speed = command.speed_rad_s or self.config.arm_speed_rad_s
        arm_q = self._arms.arm_pose(now_s)
        why = arms.target_problem(command.q_rad, speed, arm_q, self._arms.stream.limits)
        if why is not None:
            code = m.ErrorCode.REJECTED if arm_q is None else m.ErrorCode.PARAMETER
            raise self._refuse(code, f"g1 {self.device!r}: arm target refused: {why}")
        assert arm_q is not None
        changed = self._arms.target(command.q_rad, speed, arm_q, now_s)
        with self._lock:
            self._changed |= changed
        return DeviceReply(ok=True, device=self.device, written_ns=time.time_ns())

    def _fresh_state(self, now_s: float) -> idl.SportModeState_ | None:
        with self._lock:
            latest = self._latest
        if latest is None or now_s - latest[1] > self.config.link_stale_s:
            return None
        return latest[0]

    def stop_confirmed(self, now_s: float) -> bool:
        """``CONFIRM_SAMPLES`` consecutive states after the action's first write show it."""
        with self._lock:
            return self._stop_written_s is not None and self._confirming >= CONFIRM_SAMPLES

    def stop_started(self, now_s: float) -> None:
        """A new stop: confirmation starts over."""
        with self._lock:
            self._stop_written_s, self._confirming = None, 0
            self._stop_detail = None

    def still(self) -> bool | None:
        """Static (fsm_mode 0) by the newest state; None without one."""
        with self._lock:
            latest = self._latest
        return None if latest is None else bool(latest[0].fsm_mode == loco.STATIC)

    # ------------------------------------------------------------------ RPC

    def _send(self, call: loco.Call, pending: _Pending | None, service: str) -> int:
        """Write one request to ``service`` (the core holds the device's write lock); its id."""
        request_id = next(self._ids)
        if pending is not None:
            with self._lock:
                if len(self._pending) >= MAX_PENDING:
                    raise self._refuse(
                        m.ErrorCode.BUSY,
                        f"g1 {self.device!r} is busy: {MAX_PENDING} calls await the robot's answer",
                    )
                self._pending[request_id] = pending
        header = idl.RequestHeader_(identity=idl.RequestIdentity_(request_id, call.api_id))
        self._writers[service].write(idl.Request_(header=header, parameter=call.parameter))
        return request_id

    def write_stop(self, now_s: float) -> tuple[bool, str | None]:
        """The stop action's calls (``loco.stop_calls``: ``stop_move`` also ends continuous
        gait), to the service or, while ``auto`` has not found it, to every candidate name; no
        answer awaited: the state confirms it. Written with or without state: damping can
        always be activated."""
        with self._lock:
            targets = self._probe.targets
        # The stop action first, at once: the arms never delay it (they are handled beside).
        for service in targets:
            for call in loco.stop_calls(self.stop_action):
                self._send(call, None, service)
        detail = None
        if self._fresh_state(now_s) is None:
            detail = f"unconfirmed: no state on {loco.STATE_TOPIC}"
        with self._lock:
            if self._stop_written_s is None:
                self._stop_written_s, self._confirming = now_s, 0
            self._stop_detail = detail
        # The arms held where they are (or released: ``arm_on_stop``), never moved.
        if self._arms.interrupt(f"stopped ({self.stop_action})"):
            with self._lock:
                self._changed = True
        return True, detail

    def leave(self, now_s: float) -> None:
        """The agent exits: the arms go back to the robot's own controller (the weight ramped
        to 0 over ``arm_release_s``) rather than stay held by a stream that is about to end."""
        if self._arms.leave():
            with self._lock:
                self._changed = True

    def wait_left(self) -> bool:
        """Wait (bounded) until the arm stream has ended; True if it has."""
        return self._arms.wait_left()

    # ------------------------------------------------------------------ commands

    def moves(self, command: Any) -> bool:
        """Velocity and mode changes set the robot moving."""
        return not isinstance(command, (Damp, StopMove, BalanceStand, Release, ArmRelease, *READS))

    def allowed_while_latched(self, command: Any) -> bool:
        """Damping, stopping (continuous gait's way out, BalanceStand, too) and asking are ways
        to a safe state: allowed under a stop."""
        return isinstance(command, (Damp, StopMove, BalanceStand, ArmRelease, *READS))

    def _call(self, op: str, command: Any) -> loco.Call:
        """The LocoClient call of ``command``, its parameters checked first (3204)."""
        problem = None
        if isinstance(command, SetVelocity):
            c = command
            problem = loco.velocity_problem(c.vx, c.vy, c.omega, c.duration_s, self._limits)
            call = loco.call_for(op, c.vx, c.vy, c.omega, c.duration_s)
        elif isinstance(command, Move):
            c = command
            duration = loco.CONTINUOUS_MOVE_S if c.continuous else 1.0
            problem = loco.velocity_problem(c.vx, c.vy, c.vyaw, 1.0, self._limits)
            if c.continuous and not self.config.allow_continuous_move:
                problem = (
                    "move with continuous=true walks until stopped (Unitree's 864000 s); "
                    "set allow_continuous_move = true in its inventory entry to allow it, or "
                    "use set_velocity with a bounded duration_s"
                )
            call = loco.call_for(op, c.vx, c.vy, c.vyaw, duration)
        elif isinstance(command, ContinuousGait):
            call = loco.call_for(op, on=command.on)
        elif isinstance(command, SetFsmId):
            if command.fsm_id not in loco.FSM_NAMES:
                problem = f"fsm_id {command.fsm_id} is not in seed 004's table"
            call = loco.call_for(op, value=command.fsm_id)
        else:
            value: float = {  # type: ignore[dict-item]
                SetStandHeight: lambda c: c.height,
                SetSpeedMode: lambda c: c.mode,
                SetTaskId: lambda c: c.task_id,
                WaveHand: lambda c: int(c.turn),
                ShakeHand: lambda c: c.stage,
            }.get(type(command), lambda c: 0)(command)
            call = loco.call_for(op, value=value)
        if problem is not None:
            raise self._refuse(m.ErrorCode.PARAMETER, f"g1 {self.device!r}: {problem}")
        return call

    def execute(self, command: Any, now_s: float, done: Done) -> DeviceReply | None:
        """Check and call the robot; ``done`` gets its answer (or 3104 past the timeout)."""
        assert not isinstance(command, Release)  # the core serves releases
        with self._lock:
            self._counts["commands"] += 1
        if isinstance(command, (ArmTarget, ArmRelease)):
            return self._arm_command(command, now_s)
        op = OPS[type(command)]
        call = self._call(op, command)
        with self._lock:
            service = self._probe.service
        if service is None:
            raise self._refuse(
                m.ErrorCode.REJECTED,
                f"g1 {self.device!r}: {self._probe.describe()}; is its high-level service "
                "running? (`service` in the inventory names it: sport, loco or auto)",
            )
        state = self._fresh_state(now_s)
        if state is None and not isinstance(command, (Damp, *READS)):
            raise self._refuse(
                m.ErrorCode.REJECTED,
                f"g1 {self.device!r}: no fresh {loco.STATE_TOPIC} (within "
                f"{self.config.link_stale_s:g} s); is its high-level service running?",
            )
        if state is not None:
            why = loco.refusal(op, call, state.fsm_id, state.fsm_mode)
            if why is not None:
                raise self._refuse(m.ErrorCode.REJECTED, f"g1 {self.device!r}: {why}")
        written = time.time_ns()
        pending = _Pending(op, call.api_id, written, now_s + self.config.rpc_timeout_s, done)
        self._send(call, pending, service)
        with self._lock:
            self._counts["rpc_calls"] += 1
        return None
