"""Simulated D1 arms on real DDS: each arm reads ``rt/arm_Command<suffix>`` and writes
``rt/arm_Feedback<suffix>`` exactly as the arm's service does, using the shared codec.

One thread serves every arm of the process: it waits on a DDS WaitSet (command samples, or the
guard condition that shutdown and fault requests trigger) with a timeout up to the next
feedback deadline. Fault requests arrive as Zenoh queries; the Zenoh callback only queues them.

Many arms in one process (``make bench`` runs 250 per process): the deadlines are a heap, the
reports due within ``BATCH_S`` go out in one wake-up, and commands are taken only from the
readers whose condition triggered, and only when the wait says something did. Scanning every
arm on every wake-up made one process of 250 idle arms take most of a core.
"""

from __future__ import annotations

import heapq
import logging
import queue
import random
import threading
import time
from dataclasses import dataclass

import msgspec
import zenoh
from cyclonedds.core import (
    GuardCondition,
    InstanceState,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from fleet.d1 import dds
from fleet.d1.protocol import (
    ARM_REPORT_SEQ,
    ArmMessage,
    ExecuteAck,
    ReceiveAck,
    encode_message,
)
from fleet.guard import ThreadGuard
from fleet.inventory import ArmConfig, Inventory
from fleet.security.session import open_session
from fleet.sim.faults import FAULT, FaultReply, apply_fault
from fleet.sim.model import SimArmModel
from fleet.wire import keys
from fleet.wire.messages import encode
from fleet.wire.session import close_bounded

log = logging.getLogger("fleet.sim")

FEEDBACK_PERIOD_S = (0.100, 0.111)
"""The real arm's feed runs at about 9-10 Hz: each period is drawn from this range (an arm's
``sim_dynamics.feedback_hz`` sets its own)."""
MAX_PENDING_FAULTS = 64
"""Fault requests waiting for the simulator loop; more are dropped."""
STATUS_EVERY = 5
"""Status (2/3) and motor (2/4) reports go out with every 5th angle report (about 2 Hz)."""
BATCH_S = 0.002
"""Reports due this soon go out with the one due now (at most 500 wake-ups a second, however
many arms; the real arm's period itself varies by 11 ms)."""

_ANY = SampleState.Any | ViewState.Any | InstanceState.Any


SERVICES = ("marm_communication", "marm_control", "marm_controller")
"""The arm's driver services that publish ``rt/arm_Feedback`` (seed 000), one participant each
in ``sim_feedback_writers = 3`` mode: the first (this process's own participant) sends the
angles, the second the acks, the third the status and motor reports."""


@dataclass
class _SimArm:
    config: ArmConfig
    reader: DataReader
    condition: ReadCondition
    writer: DataWriter
    """Angle reports (and everything, with one feedback writer)."""
    model: SimArmModel
    ack_writer: DataWriter
    status_writer: DataWriter
    reports: int = 0


class SimulatedArms:
    """Runs simulated arms of one (domain, interface) in this process. A context manager."""

    def __init__(self, inventory: Inventory, arm_ids: list[str], seed: int = 0) -> None:
        arms = [inventory.arm(a) for a in arm_ids]
        self._rng = random.Random(seed)
        self._stop = threading.Event()
        self._faults: queue.SimpleQueue[tuple[str, zenoh.Query, bytes]] = queue.SimpleQueue()
        network = inventory.network_of(arm_ids)
        self._channel = dds.DdsChannel(*network)
        participant = self._channel.participant
        # The other two services' participants, only when an arm runs three feedback writers.
        # (The channel's Domain carries the config; more participants share it.)
        self._services = [
            DomainParticipant(self._channel.domain_id) for _ in SERVICES[1:] if _three_writers(arms)
        ]
        self._guard = GuardCondition(participant)
        self._waitset = WaitSet(participant)
        self._waitset.attach(self._guard)
        now = time.monotonic()
        self._arms: dict[str, _SimArm] = {}
        self._due: list[tuple[float, str]] = []  # heap of (next feedback time, arm id)
        self._started_s = now
        self._reports = 0  # angle-report deadlines served, and how late the latest of them was
        self._late_max_s = 0.0
        for arm in arms:
            cmd_topic = Topic(participant, dds.command_topic(arm.suffix), dds.ArmString_)
            fb_topic = Topic(participant, dds.feedback_topic(arm.suffix), dds.ArmString_)
            reader = DataReader(participant, cmd_topic, qos=dds.COMMAND_READER_QOS)
            condition = ReadCondition(reader, _ANY)
            self._waitset.attach(condition)
            writer = DataWriter(participant, fb_topic, qos=dds.FEEDBACK_WRITER_QOS)
            ack_writer = status_writer = writer
            if arm.sim_feedback_writers == 3:
                ack_writer, status_writer = (
                    DataWriter(
                        service,
                        Topic(service, dds.feedback_topic(arm.suffix), dds.ArmString_),
                        qos=dds.FEEDBACK_WRITER_QOS,
                    )
                    for service in self._services
                )
            model = SimArmModel(
                time_s=now, joint_ranges_deg=arm.joint_ranges_deg, dynamics=arm.sim_dynamics
            )
            model.faults.abnormal_value = arm.sim_error_status
            model.exec_ack_on_arrival = arm.sim_exec_ack == "on_arrival"
            model.enable_strength = arm.sim_enable == "strength"
            self._arms[arm.id] = _SimArm(
                arm, reader, condition, writer, model, ack_writer, status_writer
            )
            heapq.heappush(self._due, (now + self._period(model), arm.id))
        self._session: zenoh.Session | None = None
        self._queryables: list[zenoh.Queryable[None]] = []
        self._keys = keys.KeySpace(inventory.fleet)
        self._inventory = inventory
        self.guard = ThreadGuard("fleet sim")
        self._thread = self.guard.thread(self._run, "sim-arms")

    @property
    def participant(self) -> object:
        """The DDS participant (the device simulator of the same process shares it)."""
        return self._channel.participant

    def _period(self, model: SimArmModel) -> float:
        return self._rng.uniform(*model.dynamics.period_s())

    def start(self, with_zenoh: bool = True) -> SimulatedArms:
        """Start serving; with_zenoh also serves fault injection on the key space."""
        self._started_s = time.monotonic()
        if with_zenoh:
            self._session = open_session(self._inventory)
            for arm_id in self._arms:
                key = self._keys.arm(arm_id, keys.SIM_FAULT)
                self._queryables.append(
                    self._session.declare_queryable(key, self._on_fault_query(arm_id))
                )
        self._thread.start()
        return self

    def _on_fault_query(self, arm_id: str):  # type: ignore[no-untyped-def]
        def handler(query: zenoh.Query) -> None:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            if self._faults.qsize() >= MAX_PENDING_FAULTS:
                return  # a flood: dropping the query answers it (no reply) at once
            self._faults.put((arm_id, query, payload))
            self._guard.set(True)

        return self.guard.wrap(handler, "sim/fault")

    @property
    def session(self) -> zenoh.Session | None:
        """The fault-injection session (None before ``start`` or without Zenoh)."""
        return self._session

    def stats(self) -> tuple[int, int, float, float]:
        """(angle reports served, arms, seconds since the start, worst lateness in s)."""
        elapsed_s = time.monotonic() - self._started_s
        return self._reports, len(self._arms), elapsed_s, self._late_max_s

    def model(self, arm_id: str) -> SimArmModel:
        """The model of ``arm_id`` (for in-process inspection only)."""
        return self._arms[arm_id].model

    # ------------------------------------------------------------------ loop

    def _run(self) -> None:
        while not self._stop.is_set():
            timeout = max(0.0, min(self._due[0][0] - time.monotonic(), 0.5))
            if self._waitset.wait(duration(seconds=timeout)):  # else a timeout: nothing came
                self._guard.set(False)
                self._serve_faults()
                self._serve_commands()
            self._publish_feedback(time.monotonic())

    def _serve_commands(self) -> None:
        for arm in self._arms.values():
            if not arm.condition.triggered:  # no command sample waits in this reader
                continue
            samples = arm.reader.take(N=64)
            if not samples:
                continue
            arm.model.advance(time.monotonic())
            for sample in samples:
                text = getattr(sample, "data_", None)
                if text is None:
                    continue  # an InvalidSample: a writer went away
                self._send_acks(arm, arm.model.apply(text))

    @staticmethod
    def _send_acks(arm: _SimArm, acks: list[ArmMessage]) -> None:
        for ack in acks:
            if arm.config.sim_ack_seq == "fixed" and isinstance(ack, (ReceiveAck, ExecuteAck)):
                # The spec's examples' reading: every ack carries the arm's own seq 10.
                ack = msgspec.structs.replace(ack, seq=ARM_REPORT_SEQ)
            arm.ack_writer.write(dds.ArmString_(encode_message(ack)))

    def _publish_feedback(self, now: float) -> None:
        while self._due[0][0] <= now + BATCH_S:
            due_s, arm_id = self._due[0]
            arm = self._arms[arm_id]
            # the noise fault's jitter and the arm's own (sim_dynamics)
            jitter = self._rng.uniform(0.0, arm.model.faults.jitter_s + arm.model.dynamics.jitter_s)
            next_s = max(due_s + self._period(arm.model) + jitter, now + 0.05)
            heapq.heapreplace(self._due, (next_s, arm_id))
            self._reports += 1
            self._late_max_s = max(self._late_max_s, now - due_s)
            arm.model.advance(now)
            report = arm.model.joint_report()
            if report is not None:
                arm.writer.write(dds.ArmString_(encode_message(report)))
            self._send_acks(arm, arm.model.arrived_acks())
            if arm.reports % STATUS_EVERY == 0:
                for status in arm.model.status_reports():
                    arm.status_writer.write(dds.ArmString_(encode_message(status)))
            arm.reports += 1

    def _serve_faults(self) -> None:
        while True:
            try:
                arm_id, query, payload = self._faults.get_nowait()
            except queue.Empty:
                return
            try:
                apply_fault(self._arms[arm_id].model.faults, FAULT.decode(payload))
                reply = FaultReply(ok=True)
            except ValueError as exc:  # PayloadError, or figures out of range
                reply = FaultReply(ok=False, error=str(exc)[:1000])
            query.reply(self._keys.arm(arm_id, keys.SIM_FAULT), encode(reply))
            query.drop()

    # ------------------------------------------------------------------ shutdown

    def rate_summary(self) -> str:
        """Reports per arm and second since the start, and the worst lateness: a simulator that
        cannot keep up (too many arms for one process) shows here."""
        elapsed = max(1e-9, time.monotonic() - self._started_s)
        per_arm_hz = self._reports / len(self._arms) / elapsed
        return (
            f"{self._reports} reports of {len(self._arms)} arms in {elapsed:.1f} s: "
            f"{per_arm_hz:.2f} Hz per arm, latest {1000 * self._late_max_s:.1f} ms late at worst"
        )

    def close(self) -> None:
        """Stop the loop, then undeclare Zenoh and delete the DDS entities (idempotent)."""
        if not self._stop.is_set():
            log.info("fleet sim: %s", self.rate_summary())
        self._stop.set()
        self._guard.set(True)
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for queryable in self._queryables:
            queryable.undeclare()
        self._queryables.clear()
        if self._session is not None:
            close_bounded(self._session, "session")
            self._session = None
        for service in self._services:
            service.__del__()  # as DdsChannel.close: deletes its entities in the DDS core
        self._services.clear()
        self._channel.close()

    def __enter__(self) -> SimulatedArms:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _three_writers(arms: list[ArmConfig]) -> bool:
    return any(arm.sim_feedback_writers == 3 for arm in arms)
