"""A simulated G1 high-level motion service on real DDS: ``rt/sportmodestate`` at
``sim_rate_hz`` and ``rt/lowstate`` at ``sim_lowstate_hz`` (that rate by default; unless
``sim_state`` is off: firmware before 1.5.1), the LocoClient API over
``rt/api/<sim_service>/request|response`` (``sport`` or ``loco``) with seed 001's error codes,
and the FSM transitions of seed 004's table.

The model (``G1Model``) is pure: SetFsmId switches to a listed id (damping always; any other
only in a static state, else 3205); SetVelocity needs the walking controller (500/501/801/802,
else 3205), makes the robot dynamic (fsm_mode 1) for its duration plus ``settle_s`` of
stepping, a zero velocity ends it after ``settle_s``. SetBalanceMode (walking controller only,
allowed while dynamic: it is no FSM switch) is continuous gait with 1, as Unitree's SDK's
``ContinuousGait(true)`` sends it: the robot keeps stepping (dynamic) whatever the velocity,
a zero velocity included, until SetBalanceMode(0) (``ContinuousGait(false)`` /
``BalanceStand``), after which it stops ``settle_s`` after its velocity ends (seed 004:
"the robot will continue to step even if the current speed is 0"; balance stand: "when the
speed command is 0 and the robot is stable, the robot stops stepping"). GetBalanceMode answers
the mode. An unknown API id is 3203, a bad parameter 3204.
"""

from __future__ import annotations

import json
from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fleet.g1 import arms, idl, loco
from fleet.g1.config import G1Config
from fleet.g1.crc import low_cmd_crc, low_state_crc
from fleet.g1.relay import RPC_QOS
from fleet.wire.messages import ErrorCode

ARM_READER_QOS = Qos(
    Policy.Reliability.BestEffort, Policy.History.KeepLast(8), Policy.Durability.Volatile
)
STATE_WRITER_QOS = Qos(
    Policy.Reliability.BestEffort, Policy.History.KeepLast(1), Policy.Durability.Volatile
)


class G1Model:
    """The FSM and motion of the simulated service. Pure (times are passed in)."""

    def __init__(self, fsm_id: int, settle_s: float) -> None:
        self.fsm_id = fsm_id
        self.settle_s = settle_s
        self.moving_until_s = 0.0
        self.continuous = False
        self.velocity = (0.0, 0.0, 0.0)
        self.stand_height = float(loco.HIGH_STAND)
        self.speed_mode = 0
        self.task_id = 0
        self.task_since_s: float | None = None

    def task_time(self, now_s: float) -> float:
        """Seconds since the arm task started (0 without one)."""
        return 0.0 if self.task_since_s is None else now_s - self.task_since_s

    def fsm_mode(self, now_s: float) -> int:
        """1 (dynamic) while stepping, else 0."""
        return loco.DYNAMIC if self.continuous or now_s < self.moving_until_s else loco.STATIC

    def call(self, api_id: int, parameter: str, now_s: float) -> tuple[int, str]:
        """One request -> (status code, JSON data)."""
        if api_id not in loco.API_IDS:
            return int(ErrorCode.NOT_IMPLEMENTED), ""
        try:
            params = json.loads(parameter) if parameter else {}
        except ValueError:
            return int(ErrorCode.PARAMETER), ""
        if not isinstance(params, dict):
            return int(ErrorCode.PARAMETER), ""
        if api_id == loco.GET_FSM_ID:
            return 0, json.dumps({"data": self.fsm_id})
        if api_id == loco.GET_FSM_MODE:
            return 0, json.dumps({"data": self.fsm_mode(now_s)})
        if api_id == loco.GET_BALANCE_MODE:
            return 0, json.dumps({"data": int(self.continuous)})
        if api_id == loco.SET_FSM_ID:
            return self._set_fsm(params.get("data"), now_s), ""
        if api_id == loco.SET_BALANCE_MODE:
            return self._balance(params.get("data"), now_s), ""
        if api_id in (loco.SET_STAND_HEIGHT, loco.SET_SPEED_MODE, loco.SET_ARM_TASK):
            return self._standing_call(api_id, params.get("data"), now_s), ""
        return self._velocity(params, now_s), ""

    def _set_fsm(self, fsm_id: Any, now_s: float) -> int:
        if not isinstance(fsm_id, int) or fsm_id not in loco.FSM_NAMES:
            return int(ErrorCode.PARAMETER)
        if fsm_id != loco.DAMP_FSM and self.fsm_mode(now_s) == loco.DYNAMIC:
            return int(ErrorCode.SERVER_REJECTED)
        self.fsm_id, self.moving_until_s, self.continuous = fsm_id, 0.0, False
        self.task_since_s = None
        self.velocity = (0.0, 0.0, 0.0)
        return 0

    def _standing_call(self, api_id: int, data: Any, now_s: float) -> int:
        """SetStandHeight (0..UINT32_MAX), SetSpeedMode (0-3), SetTaskId (0-3): a standing
        controller only (else 3205)."""
        if not isinstance(data, int | float) or isinstance(data, bool):
            return int(ErrorCode.PARAMETER)
        ranges = {
            loco.SET_STAND_HEIGHT: loco.HIGH_STAND,
            loco.SET_SPEED_MODE: max(loco.SPEED_MODES),
            loco.SET_ARM_TASK: max(loco.ARM_TASKS),
        }
        if not 0 <= data <= ranges[api_id]:
            return int(ErrorCode.PARAMETER)
        if self.fsm_id not in loco.TASK_FSMS:
            return int(ErrorCode.SERVER_REJECTED)
        if api_id == loco.SET_STAND_HEIGHT:
            self.stand_height = float(data)
        elif api_id == loco.SET_SPEED_MODE:
            self.speed_mode = int(data)
        else:
            self.task_id, self.task_since_s = int(data), now_s
        return 0

    def _balance(self, mode: Any, now_s: float) -> int:
        if mode not in (0, 1):
            return int(ErrorCode.PARAMETER)
        if self.fsm_id not in loco.WALK_FSMS:
            return int(ErrorCode.SERVER_REJECTED)
        if self.continuous and mode == 0:  # it stops stepping once the velocity has ended
            self.moving_until_s = max(self.moving_until_s, now_s + self.settle_s)
        self.continuous = mode == 1
        return 0

    def _velocity(self, params: dict[str, Any], now_s: float) -> int:
        velocity, duration_s = params.get("velocity"), params.get("duration", 1.0)
        if (
            not isinstance(velocity, list)
            or len(velocity) != 3
            or not all(isinstance(v, int | float) for v in [*velocity, duration_s])
        ):
            return int(ErrorCode.PARAMETER)
        if self.fsm_id not in loco.WALK_FSMS:
            return int(ErrorCode.SERVER_REJECTED)
        self.velocity = (float(velocity[0]), float(velocity[1]), float(velocity[2]))
        if any(self.velocity):
            self.moving_until_s = now_s + float(duration_s) + self.settle_s
        else:  # stepping ends within settle_s (a repeated zero does not prolong it)
            self.moving_until_s = min(self.moving_until_s, now_s + self.settle_s)
        return 0


class SimArms:
    """rt/arm_sdk as the robot takes it: a CRC-checked LowCmd_ with a weight in
    0..1 on motor 29 blends its motors 12-28 into the robot's own pose, in the FSM states seed
    004 allows (else ignored). Pure."""

    def __init__(self) -> None:
        self.own = [0.0] * arms.MOTORS
        """The robot's own controller's pose (standing, arms down)."""
        self.weight = 0.0
        self.q_cmd = [0.0] * arms.COUNT
        self.messages = self.bad = self.ignored = 0

    def take(self, cmd: idl.LowCmd_, fsm_id: int) -> None:
        """One rt/arm_sdk message."""
        weight = float(cmd.motor_cmd[arms.WEIGHT_INDEX].q)
        if cmd.crc != low_cmd_crc(cmd) or not 0.0 <= weight <= 1.0:
            self.bad += 1
            return
        if fsm_id not in loco.ARM_SDK_FSMS:
            self.ignored += 1
            return
        self.messages += 1
        self.weight = weight
        self.q_cmd = [float(m.q) for m in cmd.motor_cmd[arms.FIRST : arms.FIRST + arms.COUNT]]

    def pose(self, fsm_id: int) -> list[float]:
        """The 29 joint positions now."""
        q = list(self.own)
        if fsm_id not in loco.ARM_SDK_FSMS:
            self.weight = 0.0  # the controller that blends is gone
        w = self.weight
        for i, target in enumerate(self.q_cmd):
            q[arms.FIRST + i] = (1 - w) * self.own[arms.FIRST + i] + w * target
        return q


class SimG1:
    """One simulated G1's DDS endpoints and model."""

    def __init__(self, config: G1Config, participant: Any, now_s: float) -> None:
        self.device = config.id
        self.config = config
        state = Topic(participant, loco.STATE_TOPIC, idl.SportModeState_)
        request = Topic(participant, loco.request_topic(config.sim_service), idl.Request_)
        response = Topic(participant, loco.response_topic(config.sim_service), idl.Response_)
        self._requests = DataReader(participant, request, qos=RPC_QOS)
        self._responses = DataWriter(participant, response, qos=RPC_QOS)
        self._state = DataWriter(participant, state, qos=STATE_WRITER_QOS)
        self.publish_state = config.sim_state
        low = Topic(participant, arms.LOWSTATE_TOPIC, idl.LowState_)
        arm = Topic(participant, arms.CMD_TOPIC, idl.LowCmd_)
        self._low = DataWriter(participant, low, qos=STATE_WRITER_QOS)
        self._arm_reader = DataReader(participant, arm, qos=ARM_READER_QOS)
        self.arms = SimArms()
        self.tick = 0
        self.readers = [self._requests, self._arm_reader]
        self.model = G1Model(config.sim_fsm_id, config.sim_settle_s)
        self.period_s = 1.0 / config.sim_rate_hz
        self.low_period_s = 1.0 / (config.sim_lowstate_hz or config.sim_rate_hz)
        self.next_s = self.next_low_s = now_s
        self.calls = 0

    def on_data(self, index: int, now_s: float) -> None:
        """Answer every request (identity echoed, status code, data); take rt/arm_sdk."""
        if index == 1:
            for cmd in self._arm_reader.take(N=64):
                if isinstance(cmd, idl.LowCmd_):
                    self.arms.take(cmd, self.model.fsm_id)
            return
        for request in self._requests.take(N=32):
            if not isinstance(request, idl.Request_):
                continue
            identity = request.header.identity
            code, data = self.model.call(int(identity.api_id), request.parameter, now_s)
            self.calls += 1
            if request.header.policy.noreply:
                continue
            header = idl.ResponseHeader_(
                identity=idl.RequestIdentity_(identity.id, identity.api_id),
                status=idl.ResponseStatus_(code),
            )
            self._responses.write(idl.Response_(header=header, data=data))

    def step(self, now_s: float) -> float:
        """Publish one sportmodestate (and a lowstate when that is due); the next time it is
        due."""
        mode = self.model.fsm_mode(now_s)
        if self.publish_state:
            model = self.model
            task_time = model.task_time(now_s)
            sample = idl.SportModeState_(model.fsm_id, mode, model.task_id, task_time)
            self._state.write(sample)
            if now_s >= self.next_low_s:
                self._low.write(self.lowstate())
                self.next_low_s = max(self.next_low_s + self.low_period_s, now_s)
        self.next_s = max(self.next_s + self.period_s, now_s)
        return self.next_s

    def lowstate(self) -> idl.LowState_:
        """rt/lowstate now: the blended pose, a level IMU, Unitree's CRC."""
        self.tick += 1
        q = self.arms.pose(self.model.fsm_id)
        motors = [idl.MotorState_(q=v) for v in q] + [idl.MotorState_() for _ in range(35 - len(q))]
        level = idl.IMUState_(quaternion=[1.0, 0.0, 0.0, 0.0])
        state = idl.LowState_(tick=self.tick, imu_state=level, motor_state=motors)
        state.crc = low_state_crc(state)
        return state
