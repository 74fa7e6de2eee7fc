"""The G1's pure parts with an injected clock: the LocoClient calls (fleet/g1/loco.py), the
service-name probe (fleet/g1/probe.py) and the simulator's model (continuous gait)."""

from __future__ import annotations

import json

import pytest

from fleet.doctor import check_g1_services
from fleet.g1 import loco
from fleet.g1.kind import summary
from fleet.g1.probe import REPEAT_S, ServiceProbe
from fleet.g1.sim import G1Model
from fleet.wire.messages import ErrorCode
from testkit.samples import g1_state

LIMITS = (0.5, 0.3, 0.5, 3.0)


def test_topics_per_service() -> None:
    assert loco.request_topic("sport") == "rt/api/sport/request"
    assert loco.response_topic("loco") == "rt/api/loco/response"
    assert loco.SERVICES == ("sport", "loco")


@pytest.mark.parametrize(
    ("op", "api_id", "parameter", "switches"),
    [
        ("damp", 7101, {"data": 1}, False),
        ("start", 7101, {"data": 500}, True),
        ("stand_up", 7101, {"data": 4}, True),
        ("balance_stand", 7102, {"data": 0}, False),
        ("stop_move", 7105, {"velocity": [0.0, 0.0, 0.0], "duration": 1.0}, False),
        ("get_fsm_id", 7001, {}, False),
    ],
)
def test_calls_are_unitree_sdks(op: str, api_id: int, parameter: dict, switches: bool) -> None:
    call = loco.call_for(op)
    assert (call.api_id, json.loads(call.parameter), call.switches_mode) == (
        api_id,
        parameter,
        switches,
    )


def test_continuous_gait_and_velocity_calls() -> None:
    on, off = loco.call_for("continuous_gait", on=True), loco.call_for("continuous_gait")
    assert (on.api_id, json.loads(on.parameter)) == (7102, {"data": 1})
    assert (off.api_id, json.loads(off.parameter)) == (7102, {"data": 0})
    move = loco.call_for("set_velocity", 0.2, -0.1, 0.3, 2.0)
    assert json.loads(move.parameter) == {"velocity": [0.2, -0.1, 0.3], "duration": 2.0}
    with pytest.raises(ValueError, match="no LocoClient call"):
        loco.call_for("jump")


def test_stop_calls() -> None:
    """stop_move: StopMove, then ContinuousGait(false) (SetBalanceMode 0); damp: SetFsmId(1)."""
    assert [c.api_id for c in loco.stop_calls("stop_move")] == [7105, 7102]
    assert [json.loads(c.parameter) for c in loco.stop_calls("damp")] == [{"data": 1}]
    with pytest.raises(ValueError):
        loco.stop_calls("hold")


def test_refusal_in_dynamic_state() -> None:
    start = loco.call_for("start")
    why = loco.refusal("start", start, 500, loco.DYNAMIC)
    assert why is not None and "dynamic state (fsm_mode 1, fsm 500 walk)" in why
    assert loco.refusal("start", start, 500, loco.STATIC) is None
    for op in ("damp", "balance_stand", "continuous_gait", "stop_move"):
        assert loco.refusal(op, loco.call_for(op), 500, loco.DYNAMIC) is None, op


def test_velocity_bounds_and_parse() -> None:
    assert loco.velocity_problem(0.5, -0.3, 0.5, 3.0, LIMITS) is None
    assert "vx 0.6" in str(loco.velocity_problem(0.6, 0, 0, 1, LIMITS))
    assert "duration_s 864000" in str(loco.velocity_problem(0.1, 0, 0, 864000.0, LIMITS))
    assert "finite" in str(loco.velocity_problem(float("nan"), 0, 0, 1, LIMITS))
    assert loco.parse_data('{"data": 500}') == 500
    assert loco.parse_data('{"data": true}') is None
    assert loco.parse_data("[1]") is None and loco.parse_data("") is None
    assert loco.fsm_name(801) == "run" and loco.fsm_name(7) == "unknown 7"


def test_probe_auto_uses_the_first_that_answered() -> None:
    probe = ServiceProbe("auto")
    assert probe.service is None and probe.targets == ("sport", "loco")
    assert probe.due(10.0) == ("sport", "loco")
    assert probe.due(10.0 + REPEAT_S / 2) == ()  # not again before REPEAT_S
    assert probe.due(10.0 + REPEAT_S) == ("sport", "loco")
    assert "no answer to GetFsmId on sport, loco yet (2 asked)" in probe.describe()
    assert probe.answer("loco")
    assert not probe.answer("sport")  # a later answer does not change the name
    assert probe.service == "loco" and probe.targets == ("loco",)
    assert probe.due(100.0) == ()
    assert probe.describe() == "loco (auto: answered GetFsmId)"


def test_probe_fixed_name() -> None:
    probe = ServiceProbe("loco")
    assert probe.service == "loco" and probe.targets == ("loco",)
    assert probe.due(0.0) == ("loco",)
    assert probe.describe() == "loco (no answer to GetFsmId yet, 1 asked)"
    assert not probe.answer("sport")  # not asked there
    assert not probe.answer("loco")  # answered, but the name was never in doubt
    assert probe.answered == ["loco"] and probe.due(5.0) == ()
    with pytest.raises(ValueError, match="none of auto, sport, loco"):
        ServiceProbe("Sport")


def _call(model: G1Model, api_id: int, now_s: float, **parameter: object) -> int:
    return model.call(api_id, json.dumps(parameter), now_s)[0]


def test_model_walk_then_stop() -> None:
    model = G1Model(500, settle_s=0.3)
    assert _call(model, loco.SET_VELOCITY, 0.0, velocity=[0.3, 0, 0], duration=2.0) == 0
    assert model.fsm_mode(1.0) == loco.DYNAMIC
    assert _call(model, loco.SET_FSM_ID, 1.0, data=4) == ErrorCode.SERVER_REJECTED  # dynamic
    assert _call(model, loco.SET_VELOCITY, 1.0, velocity=[0, 0, 0], duration=1.0) == 0
    assert model.fsm_mode(1.29) == loco.DYNAMIC and model.fsm_mode(1.3) == loco.STATIC
    assert model.fsm_mode(2.29) == loco.STATIC  # the zero ended the 2 s velocity early


def test_model_continuous_gait_needs_balance_mode_zero() -> None:
    """Seed 004: in continuous gait the robot steps even at zero velocity; Unitree's SDK turns
    it off with SetBalanceMode(0) (ContinuousGait(false)), allowed while dynamic."""
    model = G1Model(500, settle_s=0.3)
    assert _call(model, loco.SET_BALANCE_MODE, 0.0, data=1) == 0
    assert model.fsm_mode(0.0) == loco.DYNAMIC
    assert model.call(loco.GET_BALANCE_MODE, "", 0.0) == (0, '{"data": 1}')
    assert _call(model, loco.SET_VELOCITY, 1.0, velocity=[0, 0, 0], duration=1.0) == 0
    assert model.fsm_mode(100.0) == loco.DYNAMIC  # StopMove alone never ends it
    assert _call(model, loco.SET_BALANCE_MODE, 100.0, data=0) == 0  # allowed while dynamic
    assert model.fsm_mode(100.29) == loco.DYNAMIC and model.fsm_mode(100.3) == loco.STATIC
    assert _call(model, loco.SET_BALANCE_MODE, 101.0, data=2) == ErrorCode.PARAMETER


def test_model_continuous_gait_with_a_long_move_stops_on_the_stop_calls() -> None:
    """Move(continous_move=True) sends 864000 s; the stop action's two calls end it."""
    model = G1Model(500, settle_s=0.3)
    _call(model, loco.SET_BALANCE_MODE, 0.0, data=1)
    _call(model, loco.SET_VELOCITY, 0.0, velocity=[0.3, 0, 0], duration=864000.0)
    for call in loco.stop_calls("stop_move"):
        assert model.call(call.api_id, call.parameter, 5.0)[0] == 0
    assert model.fsm_mode(5.3) == loco.STATIC and model.fsm_id == 500


def test_model_damp_always_and_errors() -> None:
    model = G1Model(500, settle_s=0.3)
    _call(model, loco.SET_BALANCE_MODE, 0.0, data=1)
    assert _call(model, loco.SET_FSM_ID, 0.5, data=1) == 0  # damping, even while dynamic
    assert model.fsm_id == 1 and model.fsm_mode(0.5) == loco.STATIC
    # no walking controller: the robot refuses
    assert _call(model, loco.SET_BALANCE_MODE, 0.6, data=0) == ErrorCode.SERVER_REJECTED
    assert _call(model, loco.SET_VELOCITY, 0.6, velocity=[0.1, 0, 0]) == ErrorCode.SERVER_REJECTED
    assert model.call(7999, "", 0.7)[0] == ErrorCode.NOT_IMPLEMENTED
    assert model.call(loco.SET_FSM_ID, "{", 0.7)[0] == ErrorCode.PARAMETER
    assert _call(model, loco.SET_FSM_ID, 0.7, data=12345) == ErrorCode.PARAMETER


def test_doctor_and_status_name_the_service() -> None:
    checks = check_g1_services(
        {
            "g1/a": g1_state("sport", "sport", True),
            "g1/b": g1_state("sport", "sport", False),
            "g1/c": g1_state(None, "auto", False),
            "g1/d": None,
            "gripper/x": None,
        }
    )
    assert [(c.what.rpartition(" ")[2], c.level) for c in checks] == [
        ("g1/a", "ok"),
        ("g1/b", "fail"),
        ("g1/c", "fail"),
        ("g1/d", "warn"),
    ]
    assert 'set service = "loco" (or "auto") under [g1.b]' in checks[1].fix
    assert summary(g1_state("loco", "auto", True)).endswith("service loco (auto)")
    assert "service sport (no answer to GetFsmId)" in summary(g1_state("sport", "sport", False))
    assert "service auto: asking sport, loco" in summary(g1_state(None, "auto", False))


@pytest.mark.parametrize(
    ("op", "value", "api_id", "parameter", "switches"),
    [
        ("squat", 0, 7101, {"data": 2}, True),
        ("sit", 0, 7101, {"data": 3}, True),
        ("zero_torque", 0, 7101, {"data": 0}, True),
        ("squat2standup", 0, 7101, {"data": 706}, True),
        ("standup2squat", 0, 7101, {"data": 706}, True),
        ("lie2standup", 0, 7101, {"data": 702}, True),
        ("set_fsm_id", 1, 7101, {"data": 1}, False),
        ("set_fsm_id", 501, 7101, {"data": 501}, True),
        ("high_stand", 0, 7104, {"data": 4294967295}, False),
        ("low_stand", 0, 7104, {"data": 0}, False),
        ("set_stand_height", 0.5, 7104, {"data": 0.5}, False),
        ("set_speed_mode", 2, 7107, {"data": 2}, False),
        ("get_fsm_mode", 0, 7002, {}, False),
        ("get_balance_mode", 0, 7003, {}, False),
        ("set_task_id", 3, 7106, {"data": 3}, False),
        ("wave_hand", 0, 7106, {"data": 0}, False),
        ("wave_hand", 1, 7106, {"data": 1}, False),
        ("shake_hand", 0, 7106, {"data": 2}, False),
        ("shake_hand", 1, 7106, {"data": 3}, False),
    ],
)
def test_every_loco_client_call(
    op: str, value: float, api_id: int, parameter: dict, switches: bool
) -> None:
    """Each as Unitree's LocoClient (unitree_sdk2py g1_loco_client) sends it."""
    call = loco.call_for(op, value=value)
    assert (call.api_id, json.loads(call.parameter), call.switches_mode) == (
        api_id,
        parameter,
        switches,
    )


def test_static_rules_of_the_extra_calls() -> None:
    zero = loco.call_for("zero_torque")
    assert "only from damping" in str(loco.refusal("zero_torque", zero, 500, loco.STATIC))
    assert loco.refusal("zero_torque", zero, loco.DAMP_FSM, loco.STATIC) is None
    wave = loco.call_for("wave_hand")
    assert "standing controller" in str(loco.refusal("wave_hand", wave, 1, loco.STATIC))
    assert loco.refusal("wave_hand", wave, 500, loco.DYNAMIC) is None  # not a mode switch
    sit = loco.call_for("sit")
    assert "dynamic state" in str(loco.refusal("sit", sit, 500, loco.DYNAMIC))


def test_model_arm_task_and_stand_height() -> None:
    model = G1Model(500, settle_s=0.3)
    assert _call(model, loco.SET_ARM_TASK, 1.0, data=1) == 0
    assert model.task_id == 1 and model.task_time(1.5) == pytest.approx(0.5)
    assert _call(model, loco.SET_ARM_TASK, 1.0, data=9) == ErrorCode.PARAMETER
    assert _call(model, loco.SET_STAND_HEIGHT, 1.0, data=0) == 0 and model.stand_height == 0
    assert _call(model, loco.SET_SPEED_MODE, 1.0, data=3) == 0 and model.speed_mode == 3
    assert _call(model, loco.SET_FSM_ID, 1.0, data=1) == 0  # damped: no standing controller
    assert _call(model, loco.SET_ARM_TASK, 1.0, data=0) == ErrorCode.SERVER_REJECTED
