"""The viewer benchmark's G1 (``bench/synthetic.py``, ``bench/viewer_load.py``,
``bench/report.py``): its synthetic payloads are what the viewer decodes and draws, the
inventory names it, and the table adds its row without changing the arms' rows. The
measurement itself runs with ``python -m bench --only viewer``."""

from __future__ import annotations

import numpy as np
import pytest

from bench import report, synthetic, viewer_load
from fleet.g1 import arms
from fleet.inventory import InventoryError, parse_inventory
from fleet.wire import messages as m
from fleet.wire.payloads import G1_LOWSTATE, G1_STATE
from viewer.g1_scene import DEADBAND_RAD


def _inventory(g1s: tuple[str, ...] = ("h1",)) -> object:
    return parse_inventory(viewer_load.inventory_text(4, 7447, g1s), "inv.toml")


def test_the_inventory_has_the_g1_at_its_relay_rate() -> None:
    inventory = _inventory()
    (config,) = synthetic.g1_configs(inventory, ["h1"])  # type: ignore[arg-type]
    assert (config.id, config.relay_hz) == ("h1", 10.0)
    assert "[g1." not in viewer_load.inventory_text(4, 7447)
    with pytest.raises(InventoryError, match="no device 'b1' .known devices: h1"):
        synthetic.g1_configs(inventory, ["b1"])  # type: ignore[arg-type]  # an arm


def test_the_lowstate_decodes_as_the_viewer_does_and_moves_only_the_arms() -> None:
    poses = [
        G1_LOWSTATE.decode(m.encode(synthetic.fake_g1_lowstate(t, i, 1)))
        for i, t in enumerate(np.arange(0.0, 20.0, 0.1))
    ]
    q = np.array([low.q_rad for low in poses])
    still, moving = q[:, : synthetic.G1_LEGS_WAIST], q[:, synthetic.G1_LEGS_WAIST :]
    assert not still.any()
    lower = np.array([j[1] for j in arms.JOINTS[3:]])
    upper = np.array([j[2] for j in arms.JOINTS[3:]])
    assert np.all((lower <= moving) & (moving <= upper))
    step = np.abs(np.diff(moving, axis=0)).max(axis=1)
    assert np.all(step > DEADBAND_RAD)  # every relayed sample is drawn


def test_the_state_decodes_as_the_viewer_does() -> None:
    (config,) = synthetic.g1_configs(_inventory(), ["h1"])  # type: ignore[arg-type]
    state = G1_STATE.decode(m.encode(synthetic.fake_g1_state(config, 5, 3)))
    assert (state.fsm_id, state.link, state.estopped, state.dds_samples) == (500, "ok", False, 3)


def test_the_g1_row_and_goal_beside_the_unchanged_arm_rows() -> None:
    arms_only = {"viewer": {"10": 2.0, "50": 8.0, "200": 30.0}}
    with_g1 = {"viewer": {"10": 2.0, "50": 8.0, report.VIEWER_G1: {
        "arms": 50, "g1s": 1, "g1_relay_hz": 10.0, "viewer_cpu_percent_of_a_core": 10.0},
        "200": 30.0}}  # fmt: skip
    before, after = report.rows(arms_only), report.rows(with_g1)
    assert after[:3] == before
    assert after[3] == ("viewer CPU, 50 arms and a G1 at 10 Hz", "10 % core", "", "1.25 x 50 arms",
                        "<= 15 %", "PASS")  # fmt: skip
    goals = report.goals(with_g1)
    assert goals[: len(report.goals(arms_only))] == report.goals(arms_only)
    assert goals[-1]["goal"] == "viewer CPU, 50 arms and a G1 at 10 Hz (% of a core)"
    assert (goals[-1]["figure"], goals[-1]["limit"], goals[-1]["ok"]) == (10.0, 15.0, True)
