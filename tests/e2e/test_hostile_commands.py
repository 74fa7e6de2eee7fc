"""Hostile commands against real processes: a hold that would drag an owned arm back, delayed
commands by the thousand, commands kept in flight by the thousand, a power-on racing a power-off
stop, torque off under a holding stop, a takeover undone by the player it took the arm from.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import msgspec
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fleet.client import FleetClient
from fleet.d1 import dds
from fleet.d1 import protocol as p
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode
from testkit.harness import FleetHarness, wait_until
from testkit.hostile import assert_fleet_stops_and_serves, statuses, threads_of, wait_reset

FLEET_CLI = ("-m", "fleet.cli.main")


def _fleet(h: FleetHarness, coordinator: bool = False) -> FleetClient:
    h.start_router()
    h.start_sim()
    h.start_agent()
    if coordinator:
        h.start_coordinator()
    client = h.client()
    wait_until(lambda: h.all_links_ok(client), 30.0)
    return client


def _j0(client: FleetClient, arm: str = "a1") -> float:
    _status, joints = client.snapshot([arm], wait_s=1.0)[arm]
    assert joints is not None
    return joints.angles_deg[0]


def _fire(client: FleetClient, arm: str, commands: list[m.ArmCommand]) -> list[m.CommandReply]:
    """Send every command without waiting for the previous reply; collect all replies."""
    key = client.command_key(arm)
    handlers = [client.session.get(key, payload=m.encode(c), timeout=15.0) for c in commands]
    replies = []
    for handler in handlers:
        for reply in handler:
            if reply.ok is not None:
                data = reply.ok.payload.to_bytes()
                replies.append(msgspec.json.decode(data, type=m.CommandReply))
    return replies


def test_a_hold_never_drags_an_owned_arm_and_delayed_commands_share_one_thread(
    fleet_harness: FleetHarness,
) -> None:
    h = fleet_harness
    client = _fleet(h)
    owner = m.MoveJoint(joint=0, angle_deg=60.0, wait_reached=True, timeout_s=10.0, owner="alice")
    assert client.command("a1", owner).ok
    later = time.time_ns() + 2_000_000_000
    anonymous = client.command("a1", m.Hold(start_at_ns=later))
    assert anonymous.error is not None and anonymous.error.code == ErrorCode.PARAMETER
    other = client.command("a1", m.Hold(owner="mallory"))
    assert other.error is not None and other.error.code == ErrorCode.LEASE_EXISTS
    time.sleep(2.5)  # past the refused hold's start time: nothing may have moved the arm
    assert abs(_j0(client) - 60.0) < 2.0
    # Thousands of delayed commands once meant a thread each; now one scheduler thread, and
    # at most MAX_IN_FLIGHT of them are accepted per arm.
    agent = h.processes["agent"].pid
    before = threads_of(agent)
    start = time.time_ns() + 3_000_000_000
    delayed = [
        m.MoveJoint(joint=0, angle_deg=60.0, owner="alice", start_at_ns=start) for _ in range(400)
    ]
    replies = _fire(client, "a1", delayed)
    busy = [r for r in replies if r.error is not None and r.error.code == ErrorCode.BUSY]
    print(f"400 delayed commands: {len(busy)} busy, threads {before} -> {threads_of(agent)}")
    assert len(replies) == 400 and len(busy) >= 400 - 32
    assert threads_of(agent) <= before + 2
    client.command("a1", m.Release(owner="alice"))
    assert_fleet_stops_and_serves(h, client)


def test_commands_kept_in_flight_are_bounded(fleet_harness: FleetHarness) -> None:
    h = fleet_harness
    client = _fleet(h)
    mute = client.session.get(
        client.keys.arm("a1", keys.SIM_FAULT), payload=b'{"op":"mute_acks","on":true}'
    )
    assert [r for r in mute if r.ok is not None]
    # Muted acks keep every command in flight until its ack timeout.
    replies = _fire(client, "a1", [m.Power(on=True) for _ in range(300)])
    busy = [r for r in replies if r.error is not None and "busy" in r.error.message]
    print(f"300 commands with muted acks: {len(busy)} refused busy")
    assert len(replies) == 300 and len(busy) >= 300 - 32
    unmute = client.session.get(
        client.keys.arm("a1", keys.SIM_FAULT), payload=b'{"op":"mute_acks","on":false}'
    )
    assert [r for r in unmute if r.ok is not None]
    assert_fleet_stops_and_serves(h, client)


POWER_OFF_ARM = '\n[arms.a1]\nsuffix = "_1"\nstop_action = "power_off"\n'


def test_a_power_on_never_lands_after_a_power_off_stop(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=0, extra=POWER_OFF_ARM) as h:
        client = _fleet(h)
        assert client.command("a1", m.Power(on=True)).ok
        start = time.time_ns() + 1_000_000_000
        late_on = [m.Power(on=True, start_at_ns=start)]
        key = client.command_key("a1")
        pending = client.session.get(key, payload=m.encode(late_on[0]), timeout=5.0)
        time.sleep(0.2)
        acks = client.estop(arm="a1", timeout_s=5.0, wait_still=False)
        assert acks["a1"] is not None and acks["a1"].action == "power_off"
        replies = [r.ok.payload.to_bytes() for r in pending if r.ok is not None]
        assert replies and b'"ok":false' in replies[0], replies
        time.sleep(1.5)  # past the start time: the arm must still be powered off
        status = statuses(client, ["a1"])["a1"]
        assert status is not None and status.powered is False, status


def test_torque_off_is_refused_under_a_holding_stop(fleet_harness: FleetHarness) -> None:
    h = fleet_harness
    client = _fleet(h)
    acks = client.estop(arm="a1", timeout_s=5.0)
    assert acks["a1"] is not None and acks["a1"].action == "hold"
    for command in (m.Torque(on=False), m.Power(on=False), m.Torque(on=False, joint=1)):
        reply = client.command("a1", command)
        assert reply.error is not None and reply.error.code == ErrorCode.REJECTED, reply
        assert "fall" in reply.error.message
    status = statuses(client, ["a1"])["a1"]
    assert status is not None and status.enabled is not False and status.powered is not False
    assert_fleet_stops_and_serves(h, client)


TAKEN_SCRIPT = """
[choreo]
name = "slow sweep"

[[step]]
duration_s = 8.0
easing = "linear"
a1 = [60, 0, 0, 0, 0, 0, 30]
"""


def test_a_takeover_from_a_running_player_is_not_undone(
    fleet_harness: FleetHarness, tmp_path: Path
) -> None:
    h = fleet_harness
    client = _fleet(h)
    script = tmp_path / "sweep.toml"
    script.write_text(TAKEN_SCRIPT, encoding="utf-8")
    h.start("play", [*FLEET_CLI, "play", str(script)])
    wait_until(lambda: _j0(client) > 10.0, 15.0)
    taken = subprocess.run(
        [sys.executable, *FLEET_CLI, "move", "a1", "--joint", "0", "--angle", "-20"]
        + ["--takeover", "--wait", "--inventory", str(h.inventory_path)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert taken.returncode == 0, taken.stdout + taken.stderr
    wait_until(lambda: h.processes["play"].poll() is not None, 15.0)
    time.sleep(1.0)  # the aborted player's hold, if it were accepted, lands by now
    assert abs(_j0(client) - -20.0) < 2.0, f"the takeover was undone: j0 = {_j0(client):.1f}"


def test_nothing_is_written_after_a_stop_under_a_burst_of_power_on(tmp_path: Path) -> None:
    """Rounds of 40 power-on commands racing a power-off stop, watched on the arm's own command
    topic: once the stop's power-off is on the wire, no power-on may follow it (the arm writer
    serializes each arm's writes and checks the latch at the moment of writing)."""
    with FleetHarness(tmp_path, arms=0, extra=POWER_OFF_ARM) as h:
        client = _fleet(h)
        channel = dds.DdsChannel(h.domain, "lo")
        try:
            topic = Topic(channel.participant, dds.command_topic("_1"), dds.ArmString_)
            reader = DataReader(channel.participant, topic, qos=dds.COMMAND_READER_QOS)
            key = client.command_key("a1")
            for round_ in range(8):
                wait_reset(client, ["a1"])
                assert client.command("a1", m.Power(on=True)).ok
                reader.take(N=1000)  # forget what was written before this round
                burst = [
                    client.session.get(key, payload=m.encode(m.Power(on=True))) for _ in range(40)
                ]
                time.sleep(0.002 * round_)  # the stop lands at a different point each round
                client.put_stop(client.stop_request(source="hostile-suite"), "a1")
                for handler in burst:
                    list(handler)
                time.sleep(0.3)
                written = [
                    p.decode_command(s.data_)[1]
                    for s in reader.take(N=1000)
                    if getattr(s, "data_", None) is not None
                ]
                powers = [c.on for c in written if isinstance(c, p.SetPower)]
                assert False in powers, f"round {round_}: the stop's power off was not seen"
                after_stop = powers[powers.index(False) :]
                assert True not in after_stop, f"round {round_}: power on after the stop: {powers}"
        finally:
            channel.close()


def test_a_command_flood_while_the_agent_starts_never_takes_it_down(
    fleet_harness: FleetHarness,
) -> None:
    """Queries arrive from the moment the agent declares its command queryables, before its
    units are served: a flood that filled the command inbox then met no command service yet,
    and the failing callback took the agent down (seen when a test's flood backlog reached a
    restarted agent). Now the overflow is dropped unanswered until the units are served, then
    answered 4003 busy, and the agent comes up and serves."""
    h = fleet_harness
    h.start_router()
    h.start_sim()
    flooder = h.client()
    key = flooder.command_key("a1")
    flooding = threading.Event()
    flooding.set()
    sent = [0]

    def flood() -> None:
        deadline = time.monotonic() + 60.0  # bounded
        while flooding.is_set() and time.monotonic() < deadline:
            flooder.session.get(key, payload=b'{"op": "nope"}', timeout=0.5)
            sent[0] += 1
            if sent[0] % 50 == 0:
                time.sleep(0.001)  # the flood's own thread must not starve the test's

    thread = threading.Thread(target=flood, name="flood", daemon=True)
    thread.start()
    try:
        wait_until(lambda: sent[0] > 1000, 10.0)
        agent = h.start_agent()
        client = h.client()
        wait_until(
            lambda: (
                (s := statuses(client, ["a1"]).get("a1")) is not None
                and s.link == "ok"
                or agent.poll() is not None
            ),
            30.0,
        )
        assert agent.poll() is None, h.log("agent")[-3000:]
    finally:
        flooding.clear()
        thread.join(timeout=10.0)
        flooder.close()
    assert agent.poll() is None, h.log("agent")[-3000:]
    assert "failed" not in h.log("agent"), h.log("agent")[-3000:]

    def served() -> m.CommandReply | None:  # once the flood's backlog is drained
        reply = client.command("a1", m.MoveJoint(joint=0, angle_deg=5.0))
        return None if reply.error is not None and reply.error.code == ErrorCode.BUSY else reply

    reply = wait_until(served, 30.0, interval_s=0.2)
    assert reply.ok, reply
