"""A simulated Dex1-1 on real DDS: reads its command topic, publishes its state at
``sim_rate_hz`` (default 500 Hz) in the family the inventory names, tracks the commanded
position at ``sim_speed_rad_s``, and an object (``sim_object_rad``) stops the fingers closing
past it (the motor then squeezes: ``tau_est`` rises with the blocked error).

The model (``GripperModel``) is pure; ``SimGripper`` adds the DDS endpoints for the device
simulator host (``fleet/sim/devices.py``), which calls ``on_data`` and ``step`` on its thread.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fleet.dex1 import dds as ddx
from fleet.dex1 import idl
from fleet.dex1.codec import Q_OPEN_RAD, Limits, target_problem
from fleet.dex1.config import GripperConfig

log = logging.getLogger("fleet.sim.gripper")

GRIP_TAU_MAX = 0.5
"""The estimated effort of a full squeeze on an object (``tau_est``, Nm): the gripper's own,
whatever effort a command carries (seed 003: ``tau`` is unused, ``tau_est`` is the grip)."""


FLOAT32_MARGIN_RAD = 1e-6
"""How far above 2*pi a fully open target may arrive (float32 rounding on the wire)."""


class GripperModel:
    """Position tracking with a speed limit and an optional blocking object. Pure."""

    def __init__(self, speed_rad_s: float, object_rad: float | None, q_rad: float = Q_OPEN_RAD):
        self.q_rad = q_rad
        self.target_rad = q_rad
        self.tau = 0.0
        """The commanded effort: kept, not used (seed 003: the Dex1-1 ignores it)."""
        self.speed_rad_s = speed_rad_s
        self.object_rad = object_rad
        self.dq_rad_s = 0.0
        self.tau_est = 0.0

    def step(self, dt_s: float) -> None:
        """Advance by ``dt_s``."""
        before = self.q_rad
        limit = self.speed_rad_s * dt_s
        q = before + max(-limit, min(limit, self.target_rad - before))
        if self.object_rad is not None and q < self.object_rad <= before + 1e-9:
            q = self.object_rad
        self.q_rad = q
        self.dq_rad_s = (q - before) / dt_s if dt_s > 0 else 0.0
        blocked = self.object_rad is not None and abs(q - self.object_rad) < 1e-6
        squeeze = max(0.0, q - self.target_rad) if blocked else 0.0
        self.tau_est = min(GRIP_TAU_MAX, squeeze * 2.0)


class SimGripper:
    """One simulated gripper's DDS endpoints and model."""

    def __init__(self, config: GripperConfig, participant: Any, now_s: float) -> None:
        self.device = config.id
        self.config = config
        cmd_type, state_type = idl.FAMILIES[config.family]
        cmd_topic = Topic(participant, config.cmd_topic, cmd_type)
        state_topic = Topic(participant, config.state_topic, state_type)
        self._reader = DataReader(participant, cmd_topic, qos=ddx.COMMAND_READER_QOS)
        self._writer = DataWriter(participant, state_topic, qos=ddx.STATE_WRITER_QOS)
        self.readers = [self._reader]
        self.model = GripperModel(config.sim_speed_rad_s, config.sim_object_rad)
        # q travels as a float32: 2*pi arrives as 6.2831855, above 2*pi in float64. Without
        # the margin every fully open command (open_pct 100) was ignored here.
        self._limits = Limits(0.0, Q_OPEN_RAD + FLOAT32_MARGIN_RAD, math.inf, math.inf, math.inf)
        self.period_s = 1.0 / config.sim_rate_hz
        self.next_s = now_s
        self._last_s = now_s
        self.published = 0
        self.ignored = 0

    def on_data(self, index: int, now_s: float) -> None:
        """Take commands; the newest valid one is the target."""
        for sample in self._reader.take(N=32):
            if not hasattr(sample, "__idl_typename__"):
                continue
            target = ddx.target_of(self.config.family, sample)
            if target is None or target_problem(target, self._limits) is not None:
                self.ignored += 1
                continue
            self.model.target_rad = min(target.q_rad, Q_OPEN_RAD)
            self.model.tau = target.tau

    def step(self, now_s: float) -> float:
        """Advance the model and publish one state sample; the next time it is due."""
        self.model.step(now_s - self._last_s)
        self._last_s = now_s
        self._writer.write(self._sample())
        self.published += 1
        # Keep the grid (the rate), but never try to catch up a long gap sample by sample.
        self.next_s = max(self.next_s + self.period_s, now_s)
        return self.next_s

    def _sample(self) -> Any:
        m = self.model
        if self.config.family == "hg":
            motor = idl.HgMotorState_(
                q=m.q_rad, dq=m.dq_rad_s, tau_est=m.tau_est, temperature=[31, 30], vol=24.0
            )
            return idl.HandState_(motor_state=[motor])
        return idl.MotorStates_(
            states=[idl.GoMotorState_(q=m.q_rad, dq=m.dq_rad_s, tau_est=m.tau_est, temperature=31)]
        )
