"""Interoperability with Unitree's IDL classes from PyPI (``unitree-dds-wrapper``), a far side
nobody here wrote: its publishers send gripper state (both families), ``SportModeState_`` and
the D1's feedback (its DDS helpers with an ``ArmString_`` type), and the agents relay them; a
gripper command put on Zenoh reaches a subscriber that decodes it with its classes.

The library builds a default participant on domain 0 when ``unitree_dds_wrapper.dds_context``
is first imported (CycloneDDS's default configuration: multicast on the host's first card).
A test on a shared host must not join domain 0 by multicast, so that module is provided here
with the test's own participant (the harness's domain, loopback, unicast) before the library's
publisher and subscription helpers are imported; the helpers themselves run unchanged.
"""

import sys
import threading
import time
import types
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

from fleet.d1 import dds
from fleet.dex1.kind import KIND as GRIPPER
from fleet.dex1.messages import GripperMove
from fleet.g1.kind import KIND as G1
from fleet.wire import keys, payloads
from testkit.collect import Collector
from testkit.harness import FleetHarness, wait_until

wrapper = pytest.importorskip("unitree_dds_wrapper.idl")
from unitree_dds_wrapper.idl.unitree_go.msg import dds_ as go  # noqa: E402
from unitree_dds_wrapper.idl.unitree_hg.msg import dds_ as hg  # noqa: E402

INVENTORY = """
[grippers.wgo]
family = "go"
simulated = false
topic_suffix = "_w"

[grippers.whg]
family = "hg"
side = "right"
simulated = false
topic_suffix = "_w"

[g1.wg1]
simulated = false
"""


@contextmanager
def _wrapper_helpers(domain: int) -> Iterator[tuple[Any, Any]]:
    """The library's Publisher and Subscription classes, on the test's own participant."""
    channel = dds.DdsChannel(domain, "lo")
    context = types.ModuleType("unitree_dds_wrapper.dds_context")
    context.global_participant = channel.participant  # type: ignore[attr-defined]
    saved = {
        k: sys.modules.pop(k)
        for k in list(sys.modules)
        if k.startswith("unitree_dds_wrapper.")
        and k.rpartition(".")[2] in ("dds_context", "publisher", "subscription")
    }
    sys.modules["unitree_dds_wrapper.dds_context"] = context
    try:
        from unitree_dds_wrapper.publisher import Publisher
        from unitree_dds_wrapper.subscription import Subscription

        yield Publisher, Subscription
    finally:
        for name in ("dds_context", "publisher", "subscription"):
            sys.modules.pop(f"unitree_dds_wrapper.{name}", None)
        sys.modules.update(saved)
        channel.close()


class _Repeater:
    """Writes ``make()`` with a library publisher every ``period_s`` on its own thread."""

    def __init__(self, publisher: Any, make: Any, period_s: float) -> None:
        self._stop = threading.Event()
        self._publisher, self._make, self._period_s = publisher, make, period_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        deadline = time.monotonic() + 60.0  # bounded, whatever the test does
        while not self._stop.wait(self._period_s) and time.monotonic() < deadline:
            self._publisher.write(self._make())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)


@contextmanager
def _closing(repeaters: list[_Repeater]) -> Iterator[None]:
    """Stop the repeaters before the participant they write on is deleted."""
    try:
        yield
    finally:
        for repeater in repeaters:
            repeater.close()


def _received(subscription: Any) -> bool:
    """Whether the library's subscription (not spinning) has taken a sample by now."""
    subscription.take_one()
    return subscription.msg is not None


@pytest.fixture
def fleet(tmp_path) -> Iterator[FleetHarness]:  # type: ignore[no-untyped-def]
    with FleetHarness(tmp_path, arms=1, extra=INVENTORY) as harness:
        harness.start_router()
        harness.start(
            "devices", ["-m", "edge_agent", "--device", "wgo", "--device", "whg", "--device", "wg1"]
        )
        harness.start_agent("a1")
        yield harness


def test_wrapper_publishers_are_relayed_and_commands_decode(fleet: FleetHarness) -> None:
    ks = keys.KeySpace(fleet.inventory.fleet)
    client = fleet.client()
    session = client.session
    grip_state = GRIPPER.payloads[keys.STATE].decode
    go_states = Collector(session, ks.device("gripper", "wgo", keys.STATE), grip_state)
    hg_states = Collector(session, ks.device("gripper", "whg", keys.STATE), grip_state)
    g1_states = Collector(
        session, ks.device("g1", "wg1", keys.STATE), G1.payloads[keys.STATE].decode
    )
    joints = Collector(session, ks.arm("a1", keys.JOINTS), payloads.JOINTS.decode)
    repeaters: list[_Repeater] = []
    try:
        with _wrapper_helpers(fleet.domain) as (Publisher, Subscription), _closing(repeaters):
            go_pub = Publisher(go.MotorStates_, "rt/dex1/left/state_w")
            hg_pub = Publisher(hg.HandState_, "rt/dex1/right/state_w")
            g1_pub = Publisher(hg.SportModeState_, "rt/sportmodestate")
            arm_pub = Publisher(dds.ArmString_, "rt/arm_Feedback_1")
            # Read by the test, not by the library's own thread: that thread waits forever
            # and raised at teardown when the participant under it was deleted.
            go_cmd = Subscription(go.MotorCmds_, "rt/dex1/left/cmd_w", autospin=False)
            hg_cmd = Subscription(hg.HandCmd_, "rt/dex1/right/cmd_w", autospin=False)
            repeaters += [
                _Repeater(
                    go_pub,
                    lambda: go.MotorStates_(
                        states=[go.MotorState_(q=1.25, tau_est=0.2, temperature=33, lost=4)]
                    ),
                    0.005,
                ),
                _Repeater(
                    hg_pub,
                    lambda: hg.HandState_(
                        motor_state=[hg.MotorState_(q=4.5, temperature=[35, 36], motorstate=0)]
                    ),
                    0.005,
                ),
                _Repeater(
                    g1_pub,
                    lambda: hg.SportModeState_(fsm_id=801, fsm_mode=1, task_id=2, task_time=1.5),
                    0.01,
                ),
                _Repeater(
                    arm_pub,
                    lambda: dds.ArmString_(
                        '{"seq":10,"address":2,"funcode":1,"data":{"angle0":0,"angle1":-60,'
                        '"angle2":60,"angle3":0,"angle4":30,"angle5":0,"angle6":0}}'
                    ),
                    0.1,
                ),
            ]
            wait_until(lambda: (s := go_states.latest()) is not None and s.link == "ok", 20.0)
            s = go_states.latest()
            assert s is not None
            assert (s.q_rad, s.tau_est, s.temperature_c, s.lost) == pytest.approx(
                (1.25, 0.2, 33, 4)
            )
            assert s.opening_pct == pytest.approx(1.25 / (2 * 3.141592653589793) * 100, abs=0.01)
            wait_until(lambda: (s := hg_states.latest()) is not None and s.link == "ok", 10.0)
            h = hg_states.latest()
            assert h is not None and h.q_rad == pytest.approx(4.5) and h.temperature_c == 36
            wait_until(lambda: g1_states.latest() is not None, 10.0)
            g = g1_states.latest()
            assert g is not None
            assert (g.fsm_id, g.fsm_name, g.mode, g.task_id) == (801, "run", "dynamic", 2)
            assert g.task_time == pytest.approx(1.5)
            wait_until(lambda: joints.latest() is not None, 10.0)
            j = joints.latest()
            assert j is not None and j.angles_deg == [0, -60, 60, 0, 30, 0, 0]
            # Commands on Zenoh arrive decoded by the library's classes, with their values.
            reply = client.device_command("wgo", GripperMove(open_pct=25.0, tau=0.4, kp=3.0))
            assert reply.ok, reply
            wait_until(lambda: _received(go_cmd), 5.0)
            cmd = go_cmd.msg.cmds[0]
            assert (cmd.mode, cmd.q, cmd.tau, cmd.kp) == pytest.approx(
                (0, 3.14159265 / 2, 0.4, 3.0)
            )
            reply = client.device_command("whg", GripperMove(q_rad=2.0, kd=0.5))
            assert reply.ok, reply
            wait_until(lambda: _received(hg_cmd), 5.0)
            hcmd = hg_cmd.msg.motor_cmd[0]
            assert (hcmd.mode, hcmd.q, hcmd.kd) == pytest.approx((0, 2.0, 0.5))
            # No effort given: 0, as in seed 003's example (``tau=0.0``) and Unitree's
            # teleoperation; before, 0.5.
            assert (hcmd.dq, hcmd.tau) == (0.0, 0.0)
            assert list(hg_cmd.msg.reserve) == [0, 0, 0, 0]
            for repeater in repeaters:
                repeater.close()
        repeaters.clear()
    finally:
        for collector in (go_states, hg_states, g1_states, joints):
            collector.close()
