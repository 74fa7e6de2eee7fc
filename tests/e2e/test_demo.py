"""``fleet demo`` as an operator meets it: a reset never restarts the dance, and the demo's
children die with it however it dies (issue 15, defects 3 and 8)."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from fleet.client import FleetClient
from fleet.g1 import arms
from fleet.g1.messages import G1LowState
from fleet.inventory import load_inventory
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.payloads import CHOREO, G1_LOWSTATE
from testkit.collect import Collector
from testkit.harness import free_port, wait_until
from testkit.load import xfail_if_overloaded

REPO = Path(__file__).resolve().parents[2]


def _children_of(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                status = (entry / "status").read_text()
            except OSError:
                continue
            ppid = next(line for line in status.splitlines() if line.startswith("PPid:"))
            if int(ppid.split()[1]) == pid:
                found.append(int(entry.name))
    return found


def stop_demo(process: subprocess.Popen[bytes]) -> None:
    """Ctrl-C the demo (it stops its children), SIGKILL if it does not exit within 20 s."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=5)


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.fixture
def demo(tmp_path: Path, dds_domain: int) -> Iterator[tuple[subprocess.Popen[bytes], FleetClient]]:
    port, domain = free_port(), dds_domain
    log = open(tmp_path / "demo.log", "wb")  # noqa: SIM115 - closed below
    endpoint = f"tcp/127.0.0.1:{port}"
    inventory_path = REPO / "inventory.toml"
    process = subprocess.Popen(
        [sys.executable, "-m", "fleet.cli.main", "demo", "--no-viewer", "--for-s", "120"]
        + ["--domain", str(domain), "--endpoint", endpoint, "--inventory", str(inventory_path)],
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=REPO,
    )
    children: list[int] = []
    try:
        inventory = load_inventory(inventory_path).with_endpoints([endpoint])
        wait_until(lambda: _children_of(process.pid), 10.0)
        client = FleetClient(inventory, connect_timeout_s=20.0)
        try:
            children = _children_of(process.pid)
            yield process, client
        finally:
            client.close()
    finally:
        stop_demo(process)
        for pid in children:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        log.close()


def _joint0(client: FleetClient) -> dict[str, float]:
    return {arm: j.angles_deg[0] for arm, (_s, j) in client.snapshot(wait_s=0.5).items() if j}


def test_a_reset_never_restarts_the_demos_dance(
    demo: tuple[subprocess.Popen[bytes], FleetClient],
) -> None:
    _process, client = demo
    first = wait_until(lambda: len(_joint0(client)) == 3 and _joint0(client), 60.0)

    def dancing() -> bool:
        now = _joint0(client)
        return any(abs(now[a] - first[a]) > 2.0 for a in now if a in first)

    wait_until(dancing, 60.0)
    acks = client.estop(timeout_s=5.0)
    assert all(acks.values()), acks
    # The mixed demo (issue 14): the Dex1-1 on a1 and the G1 are stopped and confirmed too.
    assert {"a1", "a2", "a3", "gripper/gl", "g1/h1"} <= set(acks), acks
    time.sleep(1.0)
    client.reset()
    after = _joint0(client)
    time.sleep(3.0)  # the dance resumed about 1 s after a reset
    later = _joint0(client)
    moved = {a: abs(later[a] - after[a]) for a in later if a in after}
    assert max(moved.values()) < 1.0, f"the arms moved after the reset: {moved} deg"


def test_the_demos_dance_waves_the_g1_in_time_with_the_arms(
    demo: tuple[subprocess.Popen[bytes], FleetClient],
) -> None:
    """``choreo/demo.toml``'s ripple: a1's joint 0 swings to 40 deg while the G1's right elbow
    swings to -25 deg, both keyframes at the same instant of the one timeline."""
    _process, client = demo
    space = client.keys
    lows: Collector[G1LowState] = Collector(
        client.session, space.device("g1", "h1", keys.LOWSTATE), G1_LOWSTATE.decode
    )
    joints: Collector[m.Joints] = Collector(
        client.session, space.arm("a1", keys.JOINTS), payloads.JOINTS.decode
    )
    plays: Collector[m.ChoreoStatus] = Collector(client.session, space.choreo, CHOREO.decode)
    elbow = arms.FIRST + arms.RIGHT_ARM[3]

    def waved_or_stopped() -> bool:
        waved = any(math.degrees(low.q_rad[elbow]) < -24.0 for low in lows.items)
        return waved or any(play.state == "aborted" for play in plays.items)

    try:
        # the ripple's keyframe of the G1's right elbow (-25 deg; the G1 starts at 0)
        wait_until(waved_or_stopped, 90.0, explain=lambda: f"the dance: {plays.latest()}")
        stopped = [p.reason for p in plays.items if p.state == "aborted"]
        if not any(math.degrees(low.q_rad[elbow]) < -24.0 for low in lows.items):
            # A player starved of CPU past the agents' 0.5 s watchdog is stopped, by design.
            xfail_if_overloaded([f"the dance stopped before the G1 waved ({stopped[0]})"])
            raise AssertionError(f"the dance stopped before the G1 waved: {stopped}")
        at = next(t for t, low in lows.timed if math.degrees(low.q_rad[elbow]) < -24.0)
        _t, a1 = min(joints.timed, key=lambda item: abs(item[0] - at))
        print(f"G1 right elbow at -24 deg while a1's joint 0 was {a1.angles_deg[0]:.1f} deg")
        assert a1.angles_deg[0] > 25.0, a1  # a1 swings to 40 deg in the same step
    finally:
        lows.close()
        joints.close()
        plays.close()


def test_the_demos_children_die_with_it_even_by_sigkill(
    demo: tuple[subprocess.Popen[bytes], FleetClient],
) -> None:
    process, client = demo
    wait_until(lambda: len(_joint0(client)) == 3, 60.0)  # router, sim, agents, coordinator up
    children = _children_of(process.pid)
    assert len(children) >= 5, children
    process.kill()
    process.wait(timeout=5)
    # Each child gets SIGTERM from the kernel (its parent-death signal) and shuts down cleanly
    # (sessions, DDS entities): on a loaded host that took over 10 s for the last one.
    alive = lambda: [pid for pid in children if _alive(pid)]  # noqa: E731
    try:
        wait_until(lambda: not alive(), 30.0)
    except AssertionError:
        raise AssertionError(f"still alive: {[(p, _cmdline(p)) for p in alive()]}") from None


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_a_crashed_agent_is_restarted_and_the_demo_says_which(
    demo: tuple[subprocess.Popen[bytes], FleetClient], tmp_path: Path
) -> None:
    process, client = demo
    wait_until(lambda: client.agents_alive() >= {"a1", "a2", "a3"}, 60.0)
    agent = next(p for p in _children_of(process.pid) if "--arm a2" in _cmdline(p))
    os.kill(agent, signal.SIGKILL)
    wait_until(lambda: "a2" not in client.agents_alive(), 10.0)
    wait_until(lambda: "a2" in client.agents_alive(), 20.0)
    assert process.poll() is None, "one killed agent took the demo down"
    log = (tmp_path / "demo.log").read_text(errors="replace")
    assert f"agent of a2 (PID {agent}) killed by SIGKILL; restarting it" in log, log[-2000:]


def test_the_demo_with_ros2_starts_fleet_ros2_and_says_where(
    tmp_path: Path, dds_domain: int
) -> None:
    """``fleet demo --ros2``: the intro names the ROS domain and the stop service, a
    ``fleet ros2`` child runs, and the arms' joint_states reach a ROS subscriber's key."""
    from fleet.wire.session import open_client

    port, domain = free_port(), dds_domain
    endpoint = f"tcp/127.0.0.1:{port}"
    log_path = tmp_path / "demo.log"
    with open(log_path, "wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "fleet.cli.main", "demo", "--ros2", "--no-viewer"]
            + ["--no-dance", "--for-s", "120", "--domain", str(domain), "--endpoint", endpoint]
            + ["--inventory", str(REPO / "inventory.toml")],
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=REPO,
        )
    children: list[int] = []
    try:
        intro = "ros2: ROS_DOMAIN_ID=0, stop service /lab/estop (rmw_zenoh, router "
        wait_until(lambda: intro in log_path.read_text(errors="replace"), 60.0)
        children = _children_of(process.pid)
        assert any(" ros2 " in _cmdline(pid) for pid in children), children
        peer = open_client([endpoint])
        try:
            seen: list[str] = []
            sub = peer.declare_subscriber(
                "0/lab/a1/joint_states/**", lambda s: seen.append(str(s.key_expr))
            )
            wait_until(lambda: seen, 60.0)
            sub.undeclare()
        finally:
            peer.close()
        assert seen[0].startswith("0/lab/a1/joint_states/sensor_msgs::msg::dds_::JointState_/")
    finally:
        stop_demo(process)
        for pid in children:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
