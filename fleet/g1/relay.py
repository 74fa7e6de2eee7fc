"""The agent's side of one G1: ``rt/sportmodestate`` relayed with the FSM named, LocoClient
calls over DDS RPC (checked first: bounds, seed 004's dynamic-state rule, the stop latch),
and the stop action confirmed from sportmodestate.

Threads as for every device (``fleet/devices/relay.py``). RPC: one long-lived request writer
and response reader; each call gets a fresh request id, its answer is matched by that id on
the relay thread and handed to the waiting command thread (bounded wait: 3104 on timeout).
``_write`` serializes requests with the latch decision: nothing checked before a stop is
written after the stop's own request.
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from fleet.devices.base import DeviceReply
from fleet.devices.relay import LatchedRelay, Put, error_reply
from fleet.g1 import idl, loco
from fleet.g1.config import G1Config
from fleet.g1.messages import OPS, G1Command, G1State, SetVelocity
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.payloads import KIB, PayloadError, payload_kind

log = logging.getLogger("edge_agent.g1")

COMMAND = payload_kind("g1 command", G1Command, 4 * KIB)
STATE_READER_QOS = Qos(
    Policy.Reliability.BestEffort, Policy.History.KeepLast(64), Policy.Durability.Volatile
)
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
_ids = itertools.count(time.time_ns())


class G1Relay(LatchedRelay):
    """One G1 served by the agent (create on the host's start-up thread)."""

    def __init__(self, config: G1Config, participant: Any, put: Put) -> None:
        super().__init__(
            config.id, config.stop_action, put, ("rpc_calls", "rpc_timeouts", "unmatched")
        )
        self.config = config
        state = Topic(participant, loco.STATE_TOPIC, idl.SportModeState_)
        request = Topic(participant, loco.REQUEST_TOPIC, idl.Request_)
        response = Topic(participant, loco.RESPONSE_TOPIC, idl.Response_)
        self._state_reader = DataReader(participant, state, qos=STATE_READER_QOS)
        self._response_reader = DataReader(participant, response, qos=RPC_QOS)
        self._writer = DataWriter(participant, request, qos=RPC_QOS)
        self.readers = [self._state_reader, self._response_reader]
        self._latest: tuple[idl.SportModeState_, float] | None = None
        self._changed = False
        self._next_put_s = 0.0
        self._confirming = 0
        self._pending: dict[int, tuple[threading.Event, list[idl.Response_]]] = {}
        self._limits = (config.max_vx, config.max_vy, config.max_omega, config.max_duration_s)

    # ------------------------------------------------------------------ relay thread

    def on_data(self, index: int, now_s: float) -> None:
        """State samples (newest kept; stop confirmation) or RPC responses (matched by id)."""
        if index == 1:
            self._on_responses()
            return
        ack = None
        for sample in self._state_reader.take(N=64):
            if not isinstance(sample, idl.SportModeState_) or not math.isfinite(sample.task_time):
                with self._lock:
                    self._counts["bad_samples"] += int(hasattr(sample, "__idl_typename__"))
                continue
            with self._lock:
                self._counts["dds_samples"] += 1
                old = self._latest[0] if self._latest is not None else None
                if old is None or (old.fsm_id, old.fsm_mode) != (sample.fsm_id, sample.fsm_mode):
                    self._changed = True
                self._latest = (sample, now_s)
                if self._action_written_s is not None and now_s > self._action_written_s:
                    self._confirming = self._confirming + 1 if self._stopped(sample) else 0
                    if self._confirming >= CONFIRM_SAMPLES and self._latch.confirm():
                        ack = self._latch.ack()
        self._put_ack(ack)

    def _stopped(self, sample: idl.SportModeState_) -> bool:
        if self.config.stop_action == "damp":
            return sample.fsm_id == loco.DAMP_FSM
        return sample.fsm_mode == loco.STATIC

    def _on_responses(self) -> None:
        for response in self._response_reader.take(N=64):
            if not isinstance(response, idl.Response_):
                continue
            with self._lock:
                waiter = self._pending.get(response.header.identity.id)
                if waiter is None:
                    self._counts["unmatched"] += 1  # another client's, or a late answer
                    continue
                waiter[1].append(response)
            waiter[0].set()

    def tick(self, now_s: float) -> float:
        """The state on change and at the relay rate; the stop action until confirmed.
        Returns when the next tick is due (the host also ticks after each ``on_data``)."""
        with self._lock:
            self._update_rate(now_s)
            due = self._changed or now_s >= self._next_put_s
            state = self._state(now_s) if due else None
            if due:
                self._changed = False
                self._next_put_s = now_s + 1.0 / self.config.relay_hz
            action_due = self._latch.due(now_s)
            next_s = min(self._next_put_s, now_s + TICK_MAX_S)
        if state is not None:
            self._put(keys.STATE, m.encode(state), False)
        if action_due:
            self._write_stop_action(now_s)
        return next_s

    def _state(self, now_s: float) -> G1State | None:
        if self._latest is None:
            return None
        sample, at_s = self._latest
        mode = {0: "static", 1: "dynamic"}.get(sample.fsm_mode, "unknown")
        return G1State(
            stamp_ns=time.time_ns(),
            fsm_id=sample.fsm_id,
            fsm_name=loco.fsm_name(sample.fsm_id),
            fsm_mode=sample.fsm_mode,
            mode=mode,  # type: ignore[arg-type]
            task_id=sample.task_id,
            task_time=round(float(sample.task_time), 3),
            link="stale" if now_s - at_s > self.config.link_stale_s else "ok",
            estopped=self._latch.latched,
            stop_reason=self._latch.reason,
            stop_action=self.config.stop_action,
            dds_samples=self._counts["dds_samples"],
            bad_samples=self._counts["bad_samples"],
            dds_rate_hz=round(self._rate_hz, 1),
        )

    # ------------------------------------------------------------------ RPC

    def _send(self, call: loco.Call, waiter: bool) -> int:
        """Write one request (caller holds ``_write``); its id."""
        request_id = next(_ids)
        if waiter:
            with self._lock:
                if len(self._pending) >= MAX_PENDING:
                    raise OverflowError("too many calls awaiting the robot's answer")
                self._pending[request_id] = (threading.Event(), [])
        header = idl.RequestHeader_(identity=idl.RequestIdentity_(request_id, call.api_id))
        self._writer.write(idl.Request_(header=header, parameter=call.parameter))
        return request_id

    def _await(self, request_id: int) -> idl.Response_ | None:
        with self._lock:
            event, box = self._pending[request_id]
        event.wait(self.config.rpc_timeout_s)
        with self._lock:
            self._pending.pop(request_id, None)
            return box[0] if box else None

    def _write_stop_action(self, now_s: float) -> None:
        op = self.config.stop_action
        with self._write:
            with self._lock:
                if not self._latch.latched:
                    return
                first = self._latch.written_ns is None
            self._send(loco.call_for(op), waiter=False)
            with self._lock:
                self._latch.written(now_s)
                if first:
                    self._action_written_s, self._confirming = now_s, 0
                ack = self._latch.ack() if first else None
        self._put_ack(ack)

    # ------------------------------------------------------------------ commands

    def command(self, payload: bytes, principal: str) -> DeviceReply:
        """Check, call the robot, return its answer (its error code when it refuses)."""
        try:
            cmd = COMMAND.decode(payload)
        except PayloadError as exc:
            unknown = b'"op"' in payload and not any(
                f'"{o}"'.encode() in payload for o in OPS.values()
            )
            code = m.ErrorCode.NOT_IMPLEMENTED if unknown else m.ErrorCode.PARAMETER
            return self._refuse(code, str(exc))
        op = OPS[type(cmd)]
        if isinstance(cmd, SetVelocity):
            problem = loco.velocity_problem(cmd.vx, cmd.vy, cmd.omega, cmd.duration_s, self._limits)
            if problem is not None:
                return self._refuse(m.ErrorCode.PARAMETER, f"g1 {self.device!r}: {problem}")
            call = loco.call_for(op, cmd.vx, cmd.vy, cmd.omega, cmd.duration_s)
        else:
            call = loco.call_for(op)
        now_s = time.monotonic()
        with self._write:
            with self._lock:
                latest = self._latest
                reason = self._latch.reason
            if latest is None or now_s - latest[1] > self.config.link_stale_s:
                return self._refuse(
                    m.ErrorCode.REJECTED,
                    f"g1 {self.device!r}: no fresh {loco.STATE_TOPIC} (within "
                    f"{self.config.link_stale_s:g} s); is its high-level service running?",
                )
            if reason is not None and op not in ("damp", "stop_move", "get_fsm_id"):
                return self._refuse(
                    m.ErrorCode.REJECTED,
                    f"g1 {self.device!r} is stopped ({reason}); `fleet reset` releases it",
                )
            why = loco.refusal(op, call, latest[0].fsm_id, latest[0].fsm_mode)
            if why is not None:
                return self._refuse(m.ErrorCode.REJECTED, f"g1 {self.device!r}: {why}")
            try:
                request_id = self._send(call, waiter=True)
            except OverflowError as exc:
                return self._refuse(m.ErrorCode.BUSY, f"busy: {exc}")
            written = time.time_ns()
        with self._lock:
            self._counts["rpc_calls"] += 1
        response = self._await(request_id)
        if response is None:
            with self._lock:
                self._counts["rpc_timeouts"] += 1
            return error_reply(
                self.device,
                m.ErrorCode.TIMEOUT,
                f"g1 {self.device!r}: no answer to {op} within {self.config.rpc_timeout_s:g} s",
            )
        code = int(response.header.status.code)
        if response.header.identity.api_id != call.api_id:
            code = m.ErrorCode.MISMATCH  # request and response do not match (seed 001)
        if code != 0:
            return DeviceReply(
                ok=False,
                device=self.device,
                error=m.ErrorInfo(code, f"g1 {self.device!r}: the robot answered {code} to {op}"),
                written_ns=written,
            )
        result = None
        if op == "get_fsm_id":
            value = loco.parse_data(response.data)
            result = None if value is None else str(value)
        return DeviceReply(ok=True, device=self.device, written_ns=written, result=result)
