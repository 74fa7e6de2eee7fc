"""One G1's waist and arms on DDS, for its driver (``fleet/g1/relay.py``): ``rt/lowstate``
(every sample checked as it arrives, the newest good one kept), the ``rt/arm_sdk`` stream
(``fleet/g1/arms.py``'s ``ArmStream``, stepped every 20 ms into a sealed ``LowCmd_``) and a
reader of ``rt/arm_sdk`` (the weight another writer left the robot holding).

The driver calls it from the relay thread (``on_lowstate``, ``on_arm_sdk``, ``step``), the
commands thread (``target``, ``release``), the safety thread (``interrupt``) and at the agent's
exit (``leave``, ``wait_left``). The driver's lock guards its state; a DDS write is made after
it is released. A call that changes what the G1's state shows returns True: the driver puts the
state at once.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from fleet.g1 import arms, idl, loco
from fleet.g1.config import G1Config, arm_limits
from fleet.g1.crc import low_cmd_crc, low_state_crc

STATE_READER_QOS = Qos(
    Policy.Reliability.BestEffort, Policy.History.KeepLast(64), Policy.Durability.Volatile
)
ARM_READER_QOS = Qos(
    Policy.Reliability.BestEffort, Policy.History.KeepLast(8), Policy.Durability.Volatile
)
"""rt/arm_sdk as others write it: the weight a previous writer left the robot holding."""
ARM_WRITER_QOS = Qos(
    Policy.Reliability.Reliable(duration(milliseconds=5)),
    Policy.History.KeepLast(1),
    Policy.Durability.Volatile,
)
"""rt/arm_sdk: reliable matches the robot's reader whatever its reliability; depth 1, the
newest wins (a late message is worth less than the next one, 20 ms later)."""
LOWSTATE_MARGIN_RAD = 0.3
"""rt/lowstate joint positions further than this outside the limits are a bad sample."""

Own = Callable[[DataReader, Any, str, float], bool]
"""(reader, sample, topic, now): the sample is the robot's own (the driver's trust rule)."""
LowSample = tuple[idl.LowState_, list[float], float]
"""A good rt/lowstate sample, its 29 joint positions and when it arrived (monotonic s)."""


class ArmLink:
    """The rt/lowstate and rt/arm_sdk side of one G1 (create on the core's start-up thread)."""

    def __init__(self, config: G1Config, participant: Any, lock: threading.Lock, own: Own) -> None:
        self.config = config
        self._lock = lock
        self._own = own
        low = Topic(participant, arms.LOWSTATE_TOPIC, idl.LowState_)
        self.lowstate_reader = DataReader(participant, low, qos=STATE_READER_QOS)
        arm_topic = Topic(participant, arms.CMD_TOPIC, idl.LowCmd_)
        self._writer = DataWriter(participant, arm_topic, qos=ARM_WRITER_QOS)
        self.arm_sdk_reader = DataReader(participant, arm_topic, qos=ARM_READER_QOS)
        self.stream = arms.ArmStream(arm_limits(config))
        self._off = threading.Event()
        """Set while the stream is off (the agent's exit waits for it)."""
        self._low: LowSample | None = None
        self._next_s = 0.0
        self.messages = 0

    # ------------------------------------------------------------------ what the robot says

    def on_lowstate(self, now_s: float) -> int:
        """Every rt/lowstate sample of the robot's own writer checked (its CRC, finite, near
        the limits: else dropped); the newest good one kept. Returns how many were bad."""
        reader, good, bad = self.lowstate_reader, None, 0
        for sample in reader.take(N=64):
            if not isinstance(sample, idl.LowState_):
                continue
            if not self._own(reader, sample, arms.LOWSTATE_TOPIC, now_s):
                continue
            q = self._checked_q(sample)
            if q is None:
                bad += 1
            else:
                good = (sample, q, now_s)
        if good is not None:
            with self._lock:
                self._low = good
        return bad

    def _checked_q(self, sample: idl.LowState_) -> list[float] | None:
        """The 29 joint positions of a sound sample, None for a bad one."""
        q = [float(s.q) for s in sample.motor_state[: arms.MOTORS]]
        if sample.crc != low_state_crc(sample) or not all(map(math.isfinite, q)):
            return None
        limits, margin = self.stream.limits, LOWSTATE_MARGIN_RAD
        arm_q = q[arms.FIRST : arms.FIRST + arms.COUNT]
        pairs = zip(arm_q, limits.lower, limits.upper, strict=True)
        if not all(lo - margin <= v <= hi + margin for v, lo, hi in pairs):
            return None
        return q

    def on_arm_sdk(self) -> bool:
        """rt/arm_sdk as another writer (a previous agent, a script) sends it: while our
        stream is off, the robot holds the weight of its newest sound message (one with a bad
        CRC the robot drops too). True if the weight known changed."""
        mine, newest = self._writer.instance_handle, None
        for cmd in self.arm_sdk_reader.take(N=64):
            if (
                isinstance(cmd, idl.LowCmd_)
                and cmd.sample_info.publication_handle != mine
                and cmd.crc == low_cmd_crc(cmd)
            ):
                newest = float(cmd.motor_cmd[arms.WEIGHT_INDEX].q)
        if newest is None:
            return False
        with self._lock:
            known = self.stream.weight
            self.stream.seen(newest)
            return self.stream.weight != known

    def newest(self, now_s: float) -> LowSample | None:
        """The newest good rt/lowstate, None when none is fresh."""
        with self._lock:
            low = self._low
        if low is None or now_s - low[2] > self.config.link_stale_s:
            return None
        return low

    def arm_pose(self, now_s: float) -> list[float] | None:
        """The 17 measured waist and arm joints (motors 12-28), None when not fresh."""
        low = self.newest(now_s)
        return None if low is None else low[1][arms.FIRST : arms.FIRST + arms.COUNT]

    # ------------------------------------------------------------------ the stream

    def step(self, now_s: float, state: tuple[idl.SportModeState_, float] | None) -> bool:
        """Write the next rt/arm_sdk message when one is due (``state``: the newest
        sportmodestate and when it came). Without a fresh one the stream is interrupted (held
        or released: ``arm_on_stop``); in an FSM seed 004 does not allow, it ends (the robot
        ignores it). True if its phase changed."""
        with self._lock:
            stream, low = self.stream, self._low
            if not stream.active or now_s < self._next_s:
                return False
            phase = stream.phase
            if state is None or now_s - state[1] > self.config.link_stale_s:
                stream.interrupt(f"no fresh {loco.STATE_TOPIC}")
            elif state[0].fsm_id not in loco.ARM_SDK_FSMS:
                fsm = state[0].fsm_id
                stream.forget(f"fsm {fsm} {loco.fsm_name(fsm)} does not take rt/arm_sdk (seed 004)")
            step = stream.step(now_s)
            self._next_s += arms.PERIOD_S
            if self._next_s <= now_s:  # late by a period: start the cadence again
                self._next_s = now_s + arms.PERIOD_S
            if step is not None:
                self.messages += 1
            changed = stream.phase != phase
        if step is not None:
            self._writer.write(self._message(*step, low))
        return changed

    def _message(self, weight: float, q_cmd: list[float], low: LowSample | None) -> idl.LowCmd_:
        limits = self.stream.limits
        motors = [idl.MotorCmd_() for _ in range(35)]
        for i, q in enumerate(q_cmd):
            motors[arms.FIRST + i] = idl.MotorCmd_(1, q, 0.0, 0.0, limits.kp[i], limits.kd[i], 0)
        motors[arms.WEIGHT_INDEX] = idl.MotorCmd_(1, weight, 0.0, 0.0, 0.0, 0.0, 0)
        # As Unitree's low-level example: the robot's mode_machine (its model) in every command.
        mode_machine = 0 if low is None else int(low[0].mode_machine)
        message = idl.LowCmd_(mode_machine=mode_machine, motor_cmd=motors)
        message.crc = low_cmd_crc(message)
        return message

    def next_due(self) -> float | None:
        """When the next message is due (monotonic s), None while the stream is off (which
        the agent's exit waits for)."""
        with self._lock:
            streaming, due = self.stream.active, self._next_s
        if streaming:
            self._off.clear()
            return due
        self._off.set()
        return None

    def target(
        self, q_rad: list[float], speed_rad_s: float, pose: list[float], now_s: float
    ) -> bool:
        """A checked target, from the measured ``pose``; True if the phase changed."""
        with self._lock:
            if not self.stream.active:
                self._next_s = now_s
            phase = self.stream.phase
            self.stream.set_target(q_rad, speed_rad_s, pose, now_s)
            return phase != self.stream.phase

    def release(self, why: str, now_s: float) -> tuple[bool, str | None]:
        """Ramp the weight to 0 (from weight 1 on the measured pose when the robot's is
        unknown): (the phase changed, why nothing was started, if it was not)."""
        pose = self.arm_pose(now_s)
        with self._lock:
            if not self.stream.active:
                self._next_s = now_s
            changed = self.stream.release(why, pose)
            phase, weight = self.stream.phase, self.stream.weight
        if phase != "off":
            return changed, None
        if weight == 0.0:
            return changed, "nothing to release: the robot's own controller has the arms (weight 0)"
        return changed, f"nothing released: no fresh {arms.LOWSTATE_TOPIC} to start from"

    def interrupt(self, why: str) -> bool:
        """A stop: the arms held where they are (or released: ``arm_on_stop``), never moved."""
        with self._lock:
            return self.stream.interrupt(why)

    def leave(self) -> bool:
        """The agent exits: the arms go back to the robot's own controller (the weight ramped
        to 0 over ``arm_release_s``) rather than stay held by a stream that is about to end."""
        with self._lock:
            return self.stream.release("the agent exits")

    def wait_left(self) -> bool:
        """Wait until the stream has ended (bounded: its release ramp, its tail and a second);
        True if it has."""
        with self._lock:
            if not self.stream.active:
                return True
        ramp_s = self.config.arm_release_s + arms.TAIL_MESSAGES * arms.PERIOD_S
        return self._off.wait(ramp_s + 1.0)
