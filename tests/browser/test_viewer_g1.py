"""Issue 23: the G1 drawn in the viewer. The shipped model is Unitree's g1_29dof kinematics in
Unitree's motor order (the generator's output); its pose follows ``g1/<id>/lowstate`` and its
label the FSM and the stop; in a real headless Chromium, the simulated G1 is drawn and the
picture moves when its arms move through rt/arm_sdk (an ``arm_target`` through the agent)."""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import numpy as np
import pytest

from fleet.g1.arms import FIRST, JOINTS
from fleet.g1.config import G1Config, check_g1
from fleet.g1.kind import KIND
from fleet.g1.messages import ArmTarget, G1LowState
from fleet.web.access import AccessGuard, AccessPolicy, new_token
from fleet.wire import keys
from testkit.browser import Browser
from testkit.collect import Collector
from testkit.harness import FleetHarness, free_port, wait_until
from testkit.kinds import devices_fleet
from testkit.samples import g1_state
from tests.browser.test_viewer_browser import not_blank
from tests.browser.test_viewer_shift import open_page
from viewer.app import Viewer
from viewer.g1_scene import G1_URDF_PATH, G1Scene, load_g1
from viewer.scene import NORMAL, STOPPED
from viewer.server import start_server
from viewer.state import ViewerFleet

ROOT = Path(__file__).resolve().parents[2]


def _generator():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("make_g1_urdf", ROOT / "scripts/make_g1_urdf.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_shipped_g1_is_the_generators_output_in_unitrees_motor_order() -> None:
    assert G1_URDF_PATH.read_text() == _generator().urdf()
    model, meshes, joints = load_g1()
    assert len(joints) == 29
    arm_joints = [f"{name}_joint" for name, _lo, _hi in JOINTS]
    assert list(joints[FIRST:]) == arm_joints  # motors 12-28 as rt/arm_sdk names them
    assert joints[:6] == tuple(
        f"left_{j}_joint"
        for j in ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")
    )
    assert len(meshes) >= 25 and sum(len(m.faces) for m in meshes) < 10_000  # light to send
    assert (ROOT / "fleet/scene3d/assets/g1_29dof.LICENSE").read_text().startswith("BSD 3-Clause")


def test_base_xyz_is_checked() -> None:
    assert check_g1(G1Config(base_xyz=[1.0, 2.0])) is not None
    assert check_g1(G1Config(base_xyz=[1.0, 2.0, float("nan")])) is not None
    assert check_g1(G1Config(base_xyz=[1.0, 2.0, 0.0], base_yaw_deg=90.0)) is None


def _state(**changes: object) -> bytes:
    state = msgspec.structs.replace(g1_state("sport", "sport", True), **changes)
    return msgspec.json.encode(state)


def _low(q: list[float]) -> bytes:
    low = G1LowState(
        stamp_ns=1,
        q_rad=q,
        imu_rpy=[0.0, 0.0, 0.0],
        imu_quaternion=[1.0, 0, 0, 0],
        tick=1,
        bad_samples=0,
    )
    return msgspec.json.encode(low)


@pytest.fixture
def server() -> Iterator[object]:
    guard = AccessGuard(AccessPolicy(token=new_token(), host="127.0.0.1", allow_origins=()))
    server = start_server("127.0.0.1", free_port(), "g1", guard)
    try:
        yield server
    finally:
        server.stop()


def test_the_pose_follows_lowstate_and_the_label_the_fsm_and_the_stop(server) -> None:  # type: ignore[no-untyped-def]
    clock = [100.0]
    fleet = ViewerFleet((), "lab", clock=lambda: clock[0], devices={"h1": (KIND, "")})
    space = keys.KeySpace("lab")
    scene = G1Scene(server, {"h1": G1Config()}, np.zeros((0, 3)))
    assert scene.render(fleet.snapshot().devices)  # "no state" label
    assert scene._labels[0].text == "h1 · no state"
    fleet.ingest(space.device("g1", "h1", keys.STATE), _state())
    fleet.ingest(space.device("g1", "h1", keys.LOWSTATE), _low([0.0] * 29))
    assert scene.render(fleet.snapshot().devices)
    assert scene._labels[0].text == "h1 · fsm 500 walk, static" and scene._code[0] == NORMAL
    hand = [k for k, m in enumerate(scene.meshes) if m.link == "left_wrist_yaw_link"][0]
    before = np.array(scene._links[hand].batched_positions)
    assert not scene.render(fleet.snapshot().devices)  # nothing changed: nothing sent
    raised = [0.0] * 29
    raised[15] = -1.5  # left shoulder pitch: the arm forward and up
    fleet.ingest(space.device("g1", "h1", keys.LOWSTATE), _low(raised))
    assert scene.render(fleet.snapshot().devices)
    after = np.array(scene._links[hand].batched_positions)
    assert after[0, 2] - before[0, 2] > 0.2  # the hand rose
    fleet.ingest(
        space.device("g1", "h1", keys.STATE),
        _state(estopped=True, arm_phase="releasing", arm_weight=0.5),
    )
    assert scene.render(fleet.snapshot().devices)
    assert scene._code[0] == STOPPED
    assert scene._labels[0].text == "h1 · fsm 500 walk, static · arms releasing 0.50 · STOPPED"
    clock[0] += 5.0  # no lowstate since: stale
    scene.render(fleet.snapshot().devices)
    assert scene._labels[0].text.endswith("stale")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FleetHarness]:
    """Router, ``fleet sim`` (a1, gl, h1) and one agent for the card."""
    with devices_fleet(tmp_path_factory.mktemp("g1draw")) as harness:
        yield harness


def _difference(a: np.ndarray, b: np.ndarray) -> int:
    return int((np.abs(a - b).max(axis=2) > 30).sum())


def test_the_simulated_g1_is_drawn_and_moves_with_its_arms(
    fleet: FleetHarness, browser: Browser
) -> None:
    client = fleet.client()
    space = keys.KeySpace(fleet.inventory.fleet)
    lows: Collector[G1LowState] = Collector(
        client.session, space.device("g1", "h1", keys.LOWSTATE), KIND.payloads[keys.LOWSTATE].decode
    )
    wait_until(lambda: lows.latest() is not None, 30.0)
    with Viewer(fleet.inventory, port=free_port()) as viewer:
        assert viewer.g1_scene is not None
        open_page(browser, viewer.url)
        g1 = viewer.g1_scene
        wait_until(lambda: g1._text[0].startswith("h1 · fsm 500"), 15.0)
        browser.page.get_by_role("button", name="Fit view").click()
        time.sleep(1.0)  # swiftshader's first frames; every assert below polls
        first = browser.canvas("30-g1-at-rest")
        assert not_blank(first), "the 3D canvas is blank"
        # The arms through rt/arm_sdk: left shoulder pitch forward in steps the agent allows.
        for value in (-0.5, -1.0):
            q = [0.0] * 17
            q[3] = value
            reply = client.device_command("h1", ArmTarget(q_rad=q, speed_rad_s=1.0))
            assert reply.ok, reply
            wait_until(lambda v=value: abs(lows.latest().q_rad[15] - v) < 0.05, 15.0)
            wait_until(lambda v=value: abs(g1._q[0, 15] - v) < 0.05, 10.0)
        diffs: list[int] = []

        def moved() -> bool:
            diffs.append(_difference(browser.canvas("31-g1-arm-raised"), first))
            return diffs[-1] > 150

        wait_until(moved, 15.0, interval_s=0.5)
