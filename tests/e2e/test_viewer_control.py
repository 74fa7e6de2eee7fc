"""What the viewer may send, enforced on the server: read-only viewers (an observer principal, or
``--read-only``) only stop; the reset needs both steps of its confirmation; every command goes
under the viewer's own principal. Panels run on a real viser server, the commander on a real
Zenoh router.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from fleet.d1.limits import JOINT_RANGE_DEG, JointRanges
from fleet.inventory import Inventory, load_inventory
from fleet.security.session import open_session
from fleet.web.access import AccessGuard, AccessPolicy
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode
from testkit.harness import FleetHarness, free_port, wait_until
from viewer.commands import Commander, may_command
from viewer.confirm import Confirmations
from viewer.events import EventLog
from viewer.panels import FleetPanels
from viewer.server import ViewerServer, start_server

INVENTORY = Path(__file__).resolve().parents[2] / "inventory.toml"


class RecordingCommander:
    """Stands in for Commander under the panels: records what the panels ask it to send."""

    def __init__(self, read_only: bool) -> None:
        self.read_only = read_only
        self.principal = "viewer" if read_only else "operator"
        self.resets = 0
        self.reset_targets: list[str | None] = []
        self.jogs: list[tuple[str, int, float]] = []

    def reset(self, arm: str | None = None) -> bool:
        self.resets += 1
        self.reset_targets.append(arm)
        return True

    def joint_ranges(self, arm: str) -> JointRanges:
        return JOINT_RANGE_DEG

    def jog(self, arm: str, joint: int, angle_deg: float, measured_deg: float) -> bool:
        self.jogs.append((arm, joint, angle_deg))
        return True


def panels_on(server: ViewerServer, read_only: bool) -> tuple[FleetPanels, RecordingCommander]:
    """The viewer's real panels for the repository's inventory on ``server``."""
    commander = RecordingCommander(read_only)
    arms = tuple(load_inventory(INVENTORY).arms)
    panels = FleetPanels(server, arms, commander, EventLog())  # type: ignore[arg-type]
    return panels, commander


@pytest.fixture
def server() -> Iterator[ViewerServer]:
    guard = AccessGuard(AccessPolicy(token="control-test-token-0123456789"))
    started = start_server("127.0.0.1", free_port(), "control test", guard)
    try:
        yield started
    finally:
        started.stop()


# ---------------------------------------------------------------------- the confirmation


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_confirmation_needs_its_own_unexpired_request_once() -> None:
    clock = Clock()
    gate = Confirmations(window_s=30.0, clock=clock)
    assert not gate.confirm(1, "forged")  # a lone confirm
    nonce = gate.request(1)
    assert not gate.confirm(2, nonce)  # another client
    assert not gate.confirm(1, "0" * 16)  # the wrong nonce
    assert gate.confirm(1, nonce)
    assert not gate.confirm(1, nonce)  # used up
    old = gate.request(1)
    new = gate.request(1)
    assert not gate.confirm(1, old)  # a newer dialog replaced it
    gate.request(1)
    gate.cancel(1)
    assert not gate.confirm(1, new)  # cancelled
    late = gate.request(1)
    clock.now += 30.0
    assert not gate.confirm(1, late)  # expired


def test_reset_needs_both_steps_on_the_server(server: ViewerServer) -> None:
    panels, commander = panels_on(server, read_only=False)
    assert panels.reset_button is not None
    assert not panels.confirm_reset(0, "forged")
    assert commander.resets == 0 and panels.refusals["reset"] == 1
    nonce = panels.confirmations.request(0)  # what pressing "Reset stop…" does for client 0
    assert not panels.confirm_reset(1, nonce)
    assert panels.confirm_reset(0, nonce) and commander.resets == 1
    assert not panels.confirm_reset(0, nonce) and commander.resets == 1


def test_read_only_panels_have_no_reset_and_no_jog(server: ViewerServer) -> None:
    panels, commander = panels_on(server, read_only=True)
    assert panels.reset_button is None
    assert all(panel.sliders == [] for panel in panels.arm_panels)
    assert not panels.confirm_reset(0, "forged")
    assert commander.resets == 0 and commander.jogs == []


# ---------------------------------------------------------------------- the commander


class KeySpaceRecorder:
    """Everything put on the fleet's keys, and every command query (answered ok), in order."""

    def __init__(self, session: zenoh.Session, fleet: str) -> None:
        self.keys = keys.KeySpace(fleet)
        self.puts: list[str] = []
        self.queries: list[str] = []
        self._lock = threading.Lock()
        self._subscriber = session.declare_subscriber(self.keys.everything, self._on_put)
        # A FIFO queryable, answered from the test's thread (never from a Zenoh callback).
        self._queryable = session.declare_queryable(self.keys.commands("*"))

    def _on_put(self, sample: zenoh.Sample) -> None:
        with self._lock:  # a zenoh thread: store and return
            self.puts.append(str(sample.key_expr))

    def answer(self) -> None:
        """Reply ok to every command query received so far."""
        while (query := self._queryable.try_recv()) is not None:
            with self._lock:
                self.queries.append(str(query.key_expr))
            reply = m.CommandReply(True, "a1", 1, True, True, None, 1.0)
            query.reply(query.key_expr, encode(reply))

    def seen(self) -> tuple[list[str], list[str]]:
        self.answer()
        with self._lock:
            return list(self.puts), list(self.queries)

    def close(self) -> None:
        self._subscriber.undeclare()
        self._queryable.undeclare()


@contextmanager
def commander_as(
    inventory: Inventory, principal: str, read_only: bool = False
) -> Iterator[Commander]:
    """The viewer's Commander acting as ``principal``, on a session of its own."""
    acting = inventory.with_principal(principal)
    with (
        open_session(acting) as session,
        Commander(acting, session, notify=lambda *_note: None, read_only=read_only) as commander,
    ):
        yield commander


def test_who_may_command_comes_from_the_principals_role(fleet_harness: FleetHarness) -> None:
    inventory = fleet_harness.inventory
    assert not may_command(inventory.with_principal("viewer"))  # the default: an observer
    assert not may_command(inventory.with_principal("nobody-we-know"))
    for principal in ("operator", "maintainer", "coordinator"):
        assert may_command(inventory.with_principal(principal)), principal


@pytest.fixture
def recorder(fleet_harness: FleetHarness) -> Iterator[KeySpaceRecorder]:
    """A router, and a recorder of everything sent on its key space."""
    fleet_harness.start_router()
    with open_session(fleet_harness.inventory) as session:
        recording = KeySpaceRecorder(session, fleet_harness.inventory.fleet)
        try:
            yield recording
        finally:
            recording.close()


def test_an_observer_viewer_only_stops(
    fleet_harness: FleetHarness, recorder: KeySpaceRecorder
) -> None:
    space = recorder.keys
    with commander_as(fleet_harness.inventory, "viewer") as viewer:
        assert viewer.read_only
        assert viewer.jog("a1", 0, 10.0, 0.0) is False
        assert viewer.reset() is False
        assert viewer.refusals["jog"] == 1 and viewer.refusals["reset"] == 1
        stop = viewer.stop()
        wait_until(lambda: space.estop in recorder.seen()[0], 10.0)
    puts, queries = recorder.seen()
    assert space.reset not in puts and queries == []
    assert all(not key.endswith("/reset") for key in puts)
    assert stop.source == "viewer"


def test_read_only_flag_and_an_operator_viewer(
    fleet_harness: FleetHarness, recorder: KeySpaceRecorder
) -> None:
    space, inventory = recorder.keys, fleet_harness.inventory
    with commander_as(inventory, "operator", read_only=True) as flagged:
        assert flagged.read_only
        assert flagged.jog("a1", 0, 10.0, 0.0) is False and flagged.reset() is False
    with commander_as(inventory, "operator") as operator:
        assert not operator.read_only
        assert operator.jog("a1", 2, 15.0, 0.0) is True
        wait_until(lambda: recorder.seen()[1], 10.0)
        assert operator.reset() is True
        wait_until(lambda: space.reset in recorder.seen()[0], 10.0)
    # The jog went under the viewer's principal (arm/a1/cmd/operator); the read-only one sent
    # nothing.
    assert recorder.seen()[1] == [space.command("a1", "operator")]


def test_a_jog_is_one_bounded_step_from_the_measured_pose_under_the_viewers_lease(
    fleet_harness: FleetHarness,
) -> None:
    """Typing 1 into a slider that showed a stale -37 moved j1 38 deg in one step (issue 15)."""
    from viewer.commands import MAX_JOG_STEP_DEG, jog_target

    assert jog_target(1, 1.0, -37.0) == -37.0 + MAX_JOG_STEP_DEG
    assert jog_target(1, -37.5, -37.0) == -37.5
    h = fleet_harness
    client = h.start_fleet()

    def joint0() -> float:
        joints = client.snapshot(["a1"], wait_s=0.5)["a1"][1]
        assert joints is not None
        return joints.angles_deg[0]

    start = joint0()
    with commander_as(h.inventory, "operator") as operator:
        assert operator.jog("a1", 0, start + 90.0, start)  # a slider far from the arm
        wait_until(lambda: abs(joint0() - start) > MAX_JOG_STEP_DEG * 0.8, 10.0)
        time.sleep(1.0)  # it settles where the one step ends, not at the slider
        assert abs(joint0() - (start + MAX_JOG_STEP_DEG)) < 1.0, (start, joint0())
        other = client.command("a1", m.MoveJoint(joint=0, angle_deg=start, owner="script"))
        assert not other.ok and other.error is not None
        assert other.error.code == m.ErrorCode.LEASE_EXISTS and "viewer@" in other.error.message
