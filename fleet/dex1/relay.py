"""The agent's side of one Dex1-1: DDS state in at 200-500 Hz, Zenoh state out at the relay
rate (newest wins, nothing queued), grip detection on every sample, commands and stops out.

The state reader is not waited on: ``tick`` polls it at the relay's grid (at most every
``POLL_MAX_S``) and takes every sample since in one batch, decoding only the fields the relay
uses from the serialized bytes (``codec.CDR_READERS``). A 500 Hz stream costs 50 wake-ups a
second, not 500 plus the ticks between them (the devices benchmark: docs/results/bench.md).

Only the gripper's own samples count (``fleet/devices/driver.py``: its host, and on it the
first writer of its state topic), and only positions it can reach: a jump faster than
``max_speed_rad_s`` is dropped and counted (``implausible``) unless ``REANCHOR_SAMPLES`` in a
row agree (``fleet/origin/trust.py``, the arm's rule). A forged or glitched position never
reaches the relay, grip detection, a hold's target or the stop's confirmation.

Threads and locks: ``fleet/devices/driver.py`` (``_lock`` also guards the target; the core's
write lock of the device serializes every write with the stop's).
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any

from cyclonedds._clayer import ddspy_take
from cyclonedds.core import DDSException, InstanceState, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fleet.devices.base import DeviceReply, Release
from fleet.devices.driver import Done, DriverBase, LatchView, Put
from fleet.dex1 import dds as ddx
from fleet.dex1 import idl
from fleet.dex1.codec import (
    CDR_READERS,
    READERS,
    BadSample,
    Limits,
    Reading,
    Target,
    UnsupportedEncoding,
    position_cdr,
    target_problem,
)
from fleet.dex1.config import GripperConfig
from fleet.dex1.grip import GripChange, GripDetector
from fleet.dex1.messages import GripEvent, GripperHold, GripperMove, GripperState
from fleet.origin.directory import WriterDirectory
from fleet.origin.trust import SpeedCheck
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.payloads import GRIPPER_COMMAND

log = logging.getLogger("edge_agent.gripper")

TAKE_BATCH = 64
"""The reader's history depth: 128 ms of a 500 Hz stream, more than one poll period."""
POLL_MAX_S = 0.02
"""The state reader is polled at the relay rate, and at least this often (grip detection and
the stop's confirmation see every sample within this; a batch is 10 samples at 500 Hz)."""
BATCH_SPAN_S = 0.2
"""A sample's age within a batch is bounded by this (the writer's stamps are not trusted)."""
ANY_SAMPLE = SampleState.Any | ViewState.Any | InstanceState.Any
COMMAND = GRIPPER_COMMAND
STILL_RAD_S = 0.05
"""A held gripper is confirmed still below this speed (measured over 20 ms)."""
NOMINAL_PERIOD_S = 1.0 / 500.0
"""The Dex1-1 reports at up to 500 Hz: two samples are at least about this far apart."""
JUMP_MARGIN_RAD = 0.05
"""Noise a position may add on top of the fastest motion."""
REANCHOR_SAMPLES = 10
"""Consecutive positions that agree with each other but not with the one before them (20 ms
at 500 Hz) are a real jump: the position follows them."""


class GripperDriver(DriverBase):
    """One Dex1-1 served by the agent core (create on the core's start-up thread)."""

    stop_action = "hold"
    commands = COMMAND

    def __init__(
        self,
        config: GripperConfig,
        participant: Any,
        directory: WriterDirectory,
        put: Put,
        latch: LatchView,
    ) -> None:
        super().__init__(config.id, put, latch, (), config.link_stale_s, directory)
        self.config = config
        cmd_type, state_type = idl.FAMILIES[config.family]
        state_topic = Topic(participant, config.state_topic, state_type)
        cmd_topic = Topic(participant, config.cmd_topic, cmd_type)
        self._reader = DataReader(participant, state_topic, qos=ddx.STATE_READER_QOS)
        self._writer = DataWriter(participant, cmd_topic, qos=ddx.COMMAND_WRITER_QOS)
        self.readers: list[Any] = []  # polled at the relay's grid by ``tick``, never waited on
        self._state_type = state_type
        self._decode_cdr = CDR_READERS[config.family]
        self._decode_sample = READERS[config.family]
        self._limits = Limits(
            config.q_min_rad, config.q_max_rad, config.tau_max, config.kp_max, config.kd_max
        )
        self._grip = GripDetector(
            config.grip_error_rad,
            config.grip_speed_rad_s,
            config.grip_confirm_s,
            config.release_error_rad,
            config.release_s,
        )
        self._period_s = 1.0 / config.relay_hz
        self._poll_s = min(self._period_s, POLL_MAX_S)
        self._latest: tuple[Reading, float] | None = None
        self._fresh = False  # a sample arrived since the last put
        self._next_put_s = 0.0
        self._target: float | None = None
        self._speed = SpeedCheck(
            f"gripper {config.id!r}",
            config.max_speed_rad_s,
            "rad",
            NOMINAL_PERIOD_S,
            JUMP_MARGIN_RAD,
            REANCHOR_SAMPLES,
        )
        """Positions the Dex1-1 can reach (relay thread only)."""

    # ------------------------------------------------------------------ relay thread

    def on_data(self, index: int, now_s: float) -> None:
        """Not waited on (``readers`` is empty): the state reader is polled by ``tick``."""
        self._take(now_s)

    def _take(self, now_s: float) -> None:
        """Every waiting state sample, in one batch: grip detection on each sample's position
        at the sample's own time; the newest decoded in full (bounded) for the relay and the
        stop's confirmation. Only the newest reading is kept: nothing queues."""
        taken = ddspy_take(self._reader._ref, ANY_SAMPLE, TAKE_BATCH)
        if isinstance(taken, int):
            raise DDSException(taken, f"taking the state of gripper {self.device}")
        # A writer that went away leaves an invalid sample: no data, only a state change.
        # Another writer's sample is foreign (counted by ``_from_the_device``), never used.
        topic, reader = self.config.state_topic, self._reader
        valid = [
            (data, int(info.source_timestamp))
            for data, info in taken
            if info.valid_data
            and self._from_the_device(reader, int(info.publication_handle), topic, now_s)
        ]
        if not valid:
            return
        newest_ns = max(stamp for _data, stamp in valid)
        family, on_sample = self.config.family, self._grip.on_sample
        changes: list[GripChange] = []
        bad, jumps, last, at_s, why = 0, 0, None, 0.0, None
        for serialized, stamp in valid:  # reception order
            try:
                q_rad = self._position(serialized, family)
            except BadSample as exc:
                bad += 1
                log.debug("gripper %s: bad state sample: %s", self.device, exc)
                continue
            # The sample's time from the writer's clock relative to the batch's newest (only
            # differences of one clock are used; bounded and monotonic, so a forged stamp is
            # harmless).
            age_s = min(max((newest_ns - stamp) * 1e-9, 0.0), BATCH_SPAN_S)
            sample_s = max(at_s, now_s - age_s)
            implausible = self._speed.refusal((q_rad,), sample_s)
            if implausible is not None:
                jumps, why = jumps + 1, implausible
                continue
            at_s = sample_s
            change = on_sample(q_rad, at_s)
            if change is not None:
                changes.append(change)
            last = serialized
        reading = None
        if last is not None:
            try:
                reading = self._decode(last)
            except BadSample as exc:
                bad += 1
                log.debug("gripper %s: bad state sample: %s", self.device, exc)
        with self._lock:
            self._counts["bad_samples"] += bad
            self._counts["implausible"] += jumps
            self._counts["dds_samples"] += len(valid) - bad - jumps
            if bad:
                self._last_error = f"{bad} state samples did not decode"
            if why is not None:
                self._last_error = why
            if reading is not None:
                self._latest, self._fresh = (reading, at_s), True
        tau_est = reading.tau_est if reading is not None else 0.0
        for change in changes:
            event = GripEvent(
                stamp_ns=time.time_ns(),
                gripper=self.device,
                state=change.state,  # type: ignore[arg-type]
                q_rad=round(change.q_rad, 4),
                target_rad=round(change.target_rad, 4),
                error_rad=round(change.error_rad, 4),
                tau_est=tau_est,  # the batch's newest: within one poll period of the change
            )
            self._put(keys.CONTACT, m.encode(event), True)

    def _position(self, serialized: bytes, family: str) -> float:
        try:
            return position_cdr(serialized, family)
        except UnsupportedEncoding:
            return self._decode(serialized).q_rad

    def _decode(self, serialized: bytes) -> Reading:
        try:
            return self._decode_cdr(serialized)
        except UnsupportedEncoding:
            pass
        try:  # another encapsulation: the binding's generic deserialiser
            sample = self._state_type.deserialize(serialized)
            return self._decode_sample(sample)
        except BadSample:
            raise
        except Exception as exc:  # noqa: BLE001 - the binding raises anything on a hostile one
            raise BadSample(f"not a {self._state_type.__name__} ({type(exc).__name__})") from None

    def tick(self, now_s: float) -> float:
        """Poll the state (every sample since the last tick, in one batch), put the newest at
        the relay rate (a 1 Hz repeat when nothing new, so a stale link is seen); returns when
        the next tick is due (the relay's grid)."""
        self._take(now_s)
        with self._lock:
            self._update_rate(now_s)
            due = now_s >= self._next_put_s and (self._fresh or now_s - self._next_put_s >= 1.0)
            state = self._state(now_s) if due else None
            if due:
                self._fresh = False
                # Keep the grid: a late tick does not shift the next put (the rate stays).
                self._next_put_s = max(self._next_put_s + self._period_s, now_s - self._period_s)
                self._counts["relayed"] += 1
            next_s = self._next_put_s if self._next_put_s > now_s else now_s + self._poll_s
        if state is not None:
            self._put(keys.STATE, m.encode(state), False)
        return min(next_s, now_s + self._poll_s)

    def _state(self, now_s: float) -> GripperState | None:
        if self._latest is None:
            return None
        reading, at_s = self._latest
        stale = now_s - at_s > self.config.link_stale_s
        latched, reason, watched_by = self._latch()
        return GripperState(
            stamp_ns=time.time_ns(),
            q_rad=round(reading.q_rad, 5),
            opening_pct=round(reading.opening_pct, 2),
            dq_rad_s=round(reading.dq_rad_s, 4),
            tau_est=round(reading.tau_est, 4),
            temperature_c=reading.temperature_c,
            error=reading.error,
            lost=reading.lost,
            link="stale" if stale else "ok",
            target_rad=self._target,
            gripping=self._grip.gripping,
            estopped=latched,
            stop_reason=reason,
            dds_samples=self._counts["dds_samples"],
            relayed=self._counts["relayed"] + 1,
            bad_samples=self._counts["bad_samples"],
            dds_rate_hz=round(self._rate_hz, 1),
            family=self.config.family,
            mount=self.config.mount,
            watched_by=watched_by,
        )

    def stop_confirmed(self, now_s: float) -> bool:
        """The hold is confirmed once the gripper moves slower than ``STILL_RAD_S`` (measured
        after the hold's first write)."""
        with self._lock:
            written = self._stop_written_s
        if written is None or now_s - written <= 0.02:
            return False
        speed = self._grip.speed()
        return speed is not None and abs(speed) < STILL_RAD_S

    def still(self) -> bool | None:
        """Slower than ``STILL_RAD_S`` (None before two samples)."""
        speed = self._grip.speed()
        return None if speed is None else abs(speed) < STILL_RAD_S

    # ------------------------------------------------------------------ writes

    def _fresh_q(self, now_s: float) -> float | None:
        with self._lock:
            latest = self._latest
        if latest is None or now_s - latest[1] > self.config.link_stale_s:
            return None
        return latest[0].q_rad

    def _write_target(self, target: Target) -> int:
        """Write ``target`` (the core holds the device's write lock); the wall-clock time."""
        self._writer.write(ddx.command_sample(self.config.family, target))
        with self._lock:
            self._target = target.q_rad
        self._grip.on_target(target.q_rad)
        return time.time_ns()

    def _hold_target(self, q_rad: float) -> Target:
        c = self.config
        return Target(q_rad=min(max(q_rad, c.q_min_rad), c.q_max_rad), tau=c.tau, kp=c.kp, kd=c.kd)

    def write_stop(self, now_s: float) -> tuple[bool, str | None]:
        """The hold of the measured position (only a fresh one: else written by a repeat once
        one arrives)."""
        q = self._fresh_q(now_s)
        if q is None:
            return False, "no fresh position: the hold is written when one arrives"
        self._write_target(self._hold_target(q))
        with self._lock:
            if self._stop_written_s is None:
                self._stop_written_s = now_s
        return True, None

    # ------------------------------------------------------------------ commands

    def moves(self, command: Any) -> bool:
        """A move sets the fingers moving."""
        return isinstance(command, GripperMove)

    def allowed_while_latched(self, command: Any) -> bool:
        """A hold keeps the gripper where it is: allowed under a stop."""
        return isinstance(command, GripperHold)

    def execute(self, command: Any, now_s: float, done: Done) -> DeviceReply | None:
        """Check and write one command (3204 out of range, 4002 no state)."""
        assert not isinstance(command, Release)  # the core serves releases
        with self._lock:
            self._counts["commands"] += 1
        if isinstance(command, GripperHold):
            q = self._fresh_q(now_s)
            if q is None:
                raise self._refuse(m.ErrorCode.REJECTED, self._no_state())
            target = self._hold_target(q)
        else:
            if (command.open_pct is None) == (command.q_rad is None):
                raise self._refuse(m.ErrorCode.PARAMETER, "give exactly one of open_pct, q_rad")
            c = self.config
            q_rad = (
                command.q_rad
                if command.q_rad is not None
                else (command.open_pct or 0.0) / 50.0 * math.pi
            )
            target = Target(
                q_rad=q_rad,
                tau=c.tau if command.tau is None else command.tau,
                kp=c.kp if command.kp is None else command.kp,
                kd=c.kd if command.kd is None else command.kd,
            )
            problem = target_problem(target, self._limits)
            if problem is not None:
                raise self._refuse(
                    m.ErrorCode.PARAMETER, f"gripper {self.device!r}: {problem} (inventory limits)"
                )
            if self._fresh_q(now_s) is None:
                raise self._refuse(m.ErrorCode.REJECTED, self._no_state())
        written = self._write_target(target)
        return DeviceReply(ok=True, device=self.device, written_ns=written)

    def _no_state(self) -> str:
        return (
            f"gripper {self.device!r} has no fresh state on {self.config.state_topic} "
            f"(within {self.config.link_stale_s:g} s); is it powered and on this network?"
        )
