"""Both readings of every ambiguity of the D1 spec, end to end (issue 13): real processes (router,
``fleet sim`` over CycloneDDS, the edge agent), the simulator told per arm in the inventory which
reading to follow. Each arm pair runs in one fleet: one reading beside the other.
"""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import msgspec
import pytest
import zenoh
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from fleet.client import FleetClient
from fleet.d1 import dds
from fleet.d1 import protocol as p
from fleet.sim.faults import FaultReply
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.harness import FleetHarness, next_diag, wait_until


def _harness(tmp_path: Path, arms: str) -> FleetHarness:
    """A fleet whose arms are the tables in ``arms`` (the harness's own a1.. are not made)."""
    return FleetHarness(tmp_path, arms=0, extra=arms)


def _fault(client: FleetClient, fleet: str, arm: str, payload: bytes) -> FaultReply:
    key = keys.KeySpace(fleet).arm(arm, keys.SIM_FAULT)
    for reply in client.session.get(key, payload=payload, timeout=5.0):
        if reply.ok is not None:
            return msgspec.json.decode(reply.ok.payload.to_bytes(), type=FaultReply)
    raise AssertionError(f"no reply from the simulator on {key}")


# ----------------------------------------------------------------------------- ack seq

ACK_ARMS = (
    # The table's reading: acks echo the command's seq. Suffix "1": no underscore.
    '[arms.echo]\nsuffix = "1"\nsim_ack_seq = "echo"\n'
    # The examples' reading: every ack carries seq 10. Suffix "-a": any legal DDS topic name.
    '[arms.ten]\nsuffix = "-a"\nsim_ack_seq = "fixed"\n'
)

COMMANDS: list[m.ArmCommand] = [
    m.MoveJoint(joint=0, angle_deg=5.0),
    m.MoveJoints(angles_deg=[0.0, -10.0, 10.0, 0.0, 5.0, 0.0, 20.0], mode=0),
    m.Torque(on=True),  # two D1 commands (the measured pose as target, then enable): 4 acks
    m.Power(on=True),
    m.Zero(),
]


def test_acks_echoing_the_seq_or_carrying_10_both_complete_commands(tmp_path: Path) -> None:
    """Before: every command to the arm answering seq 10 failed 3104 after 0.5 s although the
    arm executed it (and suffixes "1" and "-a" were refused by the inventory)."""
    with _harness(tmp_path, ACK_ARMS) as harness:
        client = harness.start_fleet()
        for arm in ("echo", "ten"):
            for command in COMMANDS:
                reply = client.command(arm, command)
                assert reply.ok, (arm, command, reply.error)
                assert reply.received and reply.executed, (arm, command, reply)
        # Several commands in flight at once (a client that does not wait): each is answered.
        with ThreadPoolExecutor(6) as pool:
            many = list(
                pool.map(
                    lambda j: client.command("ten", m.MoveJoint(joint=j, angle_deg=3.0)), range(6)
                )
            )
        assert all(r.ok and r.received and r.executed for r in many), many
        acks_per_arm = 2 * (len(COMMANDS) + 1 + 6)  # receive + execute per D1 command
        echo = next_diag(client, harness.inventory.fleet, "echo")
        ten = next_diag(client, harness.inventory.fleet, "ten")
        assert (echo.acks_unmatched, echo.acks_ignored, echo.ack_timeouts) == (0, 0, 0), echo
        assert ten.acks_unmatched >= acks_per_arm and ten.ack_timeouts == 0, ten
        assert ten.acks_ignored == 0, ten


# ----------------------------------------------------------------------------- feedback writers

THREE_WRITER_ARMS = (
    '[arms.three]\nsuffix = "_1"\nsim_feedback_writers = 3\n'
    '[arms.unload]\nsuffix = "_2"\nsim_feedback_writers = 3\nstop_action = "unload"\n'
)

REACHED = m.MoveJoint(joint=1, angle_deg=-20.0, wait_reached=True, timeout_s=8.0)


def _relay_hz(client: FleetClient, fleet: str, arm: str, samples: int = 30) -> float:
    """Joint samples per second the agent relays for ``arm``, over ``samples`` of them (by the
    agent's stamps)."""
    stamps: list[int] = []

    def on_sample(sample: zenoh.Sample) -> None:
        stamps.append(payloads.JOINTS.decode(sample.payload.to_bytes()).stamp_ns)

    key = keys.KeySpace(fleet).arm(arm, keys.JOINTS)
    subscriber = client.session.declare_subscriber(key, on_sample)
    try:
        wait_until(lambda: len(stamps) >= samples, samples * 0.2 + 5.0)
    finally:
        subscriber.undeclare()
    return (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9)


@pytest.mark.timing
def test_feedback_from_three_writers_relays_completes_commands_and_confirms_stops(
    tmp_path: Path,
) -> None:
    """Before: the agent trusted only the first writer it heard: the acks (another writer) were
    foreign, every command failed 3104, and status never reached the fleet."""
    with FleetHarness(tmp_path, arms=0, extra=THREE_WRITER_ARMS) as harness:
        client = harness.start_fleet()
        fleet = harness.inventory.fleet
        for arm in ("three", "unload"):
            for command in [*COMMANDS, REACHED]:
                reply = client.command(arm, command)
                assert reply.ok, (arm, command, reply.error)
                assert reply.received and reply.executed, (arm, command, reply)
        hz = {arm: _relay_hz(client, fleet, arm) for arm in ("three", "unload")}
        print(f"\nrelay with three feedback writers: {hz} Hz")
        assert all(8.0 <= rate <= 11.5 for rate in hz.values()), hz
        status = client.snapshot(["three"])["three"][0]
        assert status is not None and status.enabled and status.powered, status
        # A stop of each kind is confirmed from feedback: hold by the angles (one writer),
        # unload by the status (another).
        acks = {arm: client.estop(arm, reason="three writers", timeout_s=5.0)[arm] for arm in hz}
        assert all(a is not None and a.done for a in acks.values()), acks
        assert acks["unload"] is not None and acks["unload"].confirmed_ns is not None
        for arm in hz:
            diag = next_diag(client, fleet, arm)
            assert diag.foreign_feedback == 0 and diag.ack_timeouts == 0, diag
            assert diag.implausible_feedback == 0, diag


def test_a_second_angle_writer_beside_the_arms_services_is_foreign(tmp_path: Path) -> None:
    """A rogue process on the arm's own host (this test process, on loopback like the sim)
    sends forged angles: the arm's angle writer keeps the report, the forged pose is never
    relayed, and the arm's acks from its other writers still complete commands."""
    with FleetHarness(tmp_path, arms=0, extra=THREE_WRITER_ARMS) as harness:
        client = harness.start_fleet()
        fleet = harness.inventory.fleet
        channel = dds.DdsChannel(harness.domain)
        try:
            topic = Topic(channel.participant, dds.feedback_topic("_1"), dds.ArmString_)
            rogue = DataWriter(channel.participant, topic, qos=dds.FEEDBACK_WRITER_QOS)
            forged = p.JointAngles((80.0, 30.0, 30.0, 0.0, 0.0, 0.0, 10.0))
            before = next_diag(client, fleet, "three").foreign_feedback
            for _ in range(30):
                rogue.write(dds.ArmString_(p.encode_message(forged)))
                reply = client.command("three", m.MoveJoint(joint=0, angle_deg=3.0))
                assert reply.ok and reply.executed, reply.error
                if next_diag(client, fleet, "three").foreign_feedback > before:
                    break
            joints = client.snapshot(["three"])["three"][1]
            assert joints is not None and abs(joints.angles_deg[0] - 3.0) < 5.0, joints
            diag = next_diag(client, fleet, "three")
            assert diag.foreign_feedback > before, diag
        finally:
            channel.close()


def test_three_writer_mode_is_checked_by_the_inventory() -> None:
    from fleet.inventory import InventoryError, parse_inventory

    text = '[fleet]\nname = "x"\n[arms.a1]\nsim_feedback_writers = 2\n'
    try:
        parse_inventory(text)
    except InventoryError as exc:
        assert "sim_feedback_writers must be 1 or 3" in str(exc)
    else:
        raise AssertionError("sim_feedback_writers = 2 was accepted")


# ----------------------------------------------------------------------------- execute ack

ARRIVAL_ARMS = (
    # "Executed" as "motion finished": a slow arm whose execute ack comes on arrival.
    '[arms.slow]\nsuffix = "_1"\nsim_exec_ack = "on_arrival"\n'
    "sim_dynamics = {mode1 = {rate_deg_s = 30.0, lag_s = 0.3}}\n"
)


def test_a_long_move_and_a_return_to_zero_complete_past_two_seconds(tmp_path: Path) -> None:
    """Before: one execute-ack timeout, 2 s, for every op: a move or a return to zero whose
    execute ack comes when the motion finished failed 3104 although the arm did it. And an ack
    whose seq is neither ours nor 10 was credited to our oldest command."""
    with _harness(tmp_path, ARRIVAL_ARMS) as harness:
        client = harness.start_fleet()
        fleet = harness.inventory.fleet
        for command in (m.MoveJoint(joint=0, angle_deg=80.0), m.Zero()):
            reply = client.command("slow", command)
            assert reply.ok and reply.executed, (command, reply)
            assert reply.latency_ms > 2000.0, reply  # it did take longer than the old timeout
        channel = dds.DdsChannel(harness.domain)
        try:
            topic = Topic(channel.participant, dds.feedback_topic("_1"), dds.ArmString_)
            other = DataWriter(channel.participant, topic, qos=dds.FEEDBACK_WRITER_QOS)
            # Another client's command acked on the arm's topic: never ours.
            foreign = dds.ArmString_(p.encode_message(p.ExecuteAck(4242, False)))

            def counted() -> bool:
                other.write(foreign)
                return next_diag(client, fleet, "slow").acks_foreign > 0

            wait_until(counted, 15.0)
            reply = client.command("slow", m.MoveJoint(joint=0, angle_deg=2.0))
            assert reply.ok and reply.executed, reply
        finally:
            channel.close()


# ----------------------------------------------------------------------------- enable strength

ENABLE_ARMS = (
    # The note's reading (mode is a 0..80000 strength): mode 1 leaves the arm limp.
    '[arms.limp]\nsuffix = "_1"\nsim_enable = "strength"\n'
    '[arms.locked]\nsuffix = "_2"\nsim_enable = "strength"\nenable_mode = 80000\n'
)


def test_an_enable_that_leaves_the_arm_limp_is_warned_naming_the_setting(tmp_path: Path) -> None:
    """Before: mode 1 was sent and the fleet believed the arm enabled, limp or not."""
    with _harness(tmp_path, ENABLE_ARMS) as harness:
        client = harness.start_fleet()
        for arm in ("limp", "locked"):
            assert client.command(arm, m.MoveJoint(joint=1, angle_deg=30.0, wait_reached=True)).ok
            reply = client.command(arm, m.Torque(on=True))
            assert reply.ok and reply.executed, reply
        warned = wait_until(lambda: "does not hold its pose" in harness.log("agent"), 10.0)
        assert warned
        log = harness.log("agent")
        assert "arm 'limp'" in log and "enable_mode 1" in log and "enable_mode = 80000" in log
        assert "arm 'locked': the arm does not hold" not in log, log[-3000:]
        # Later the locked arm still stands where it was enabled (reached within 2 deg of 30).
        sag = next_diag(client, harness.inventory.fleet, "limp")
        assert sag.last_error is not None and "does not hold its pose" in sag.last_error
        joints = client.snapshot(["locked"])["locked"][1]
        assert joints is not None and abs(joints.angles_deg[1] - 30.0) <= 2.5, joints
        strength = client.command("limp", m.Torque(on=True, strength=80000))
        assert strength.ok, strength


# ----------------------------------------------------------------------------- error_status

ERROR_ARMS = (
    '[arms.table]\nsuffix = "_1"\n'  # the table's reading: 0 is abnormal
    '[arms.bits]\nsuffix = "_2"\nsim_error_status = 132\n'  # the plan's: a bitfield (0x84)
)


def test_error_status_zero_or_a_bitfield_both_read_abnormal(tmp_path: Path) -> None:
    """Before: any error_status but 0/1 made the whole status report malformed: enabled and
    powered went stale and the error was never seen."""
    with _harness(tmp_path, ERROR_ARMS) as harness:
        client = harness.start_fleet()
        fleet = harness.inventory.fleet
        for arm in ("table", "bits"):
            assert _fault(client, fleet, arm, b'{"op":"error_status","error":true}').ok

        def statuses() -> dict[str, m.ArmStatus] | None:
            snapshot = {a: s for a, (s, _j) in client.snapshot(["table", "bits"]).items()}
            if all(s is not None and s.error for s in snapshot.values()):
                return snapshot  # type: ignore[return-value]
            return None

        seen = wait_until(statuses, 10.0)
        assert (seen["table"].error_status, seen["bits"].error_status) == (0, 132)
        assert all(s.enabled and s.powered and s.link == "ok" for s in seen.values()), seen
        # Another bitfield, set by a fault; then normal again.
        assert _fault(client, fleet, "bits", b'{"op":"error_status","value":5}').ok
        wait_until(lambda: client.snapshot(["bits"])["bits"][0].error_status == 5, 10.0)
        assert _fault(client, fleet, "bits", b'{"op":"error_status","error":false}').ok
        normal = wait_until(
            lambda: (s := client.snapshot(["bits"])["bits"][0]).error_status == 1 and s, 10.0
        )
        assert normal.error is False
        diag = next_diag(client, fleet, "bits")
        assert diag.malformed == 0, diag
        log = harness.log("agent")
        assert "arm bits: error_status 132 (abnormal; 0x84 as a bitfield)" in log, log[-2000:]
        assert "arm table: error_status 0 (abnormal" in log, log[-2000:]
        # A value that cannot report an abnormal arm is refused by the simulator, not applied.
        assert not _fault(client, fleet, "bits", b'{"op":"error_status","value":1}').ok


# ----------------------------------------------------------------------------- gripper unit

GRIPPER_ARMS = (
    '[arms.servo]\nsuffix = "_1"\n'  # the default reading: servo degrees, 0 closed .. 65 open
    '[arms.inverted]\nsuffix = "_2"\ngripper_closed_deg = 100.0\ngripper_open_deg = 0.0\n'
)


def test_each_arm_takes_its_own_gripper_range(tmp_path: Path) -> None:
    """Before: angle6 was 0..65 for every arm: an arm whose gripper reads 0..100 could never be
    closed past 65 (and the inventory refused the fields)."""
    with _harness(tmp_path, GRIPPER_ARMS) as harness:
        client = harness.start_fleet()
        closed = m.MoveJoint(joint=6, angle_deg=90.0, wait_reached=True, timeout_s=8.0)
        reply = client.command("inverted", closed)
        assert reply.ok and reply.reached, reply.error
        refused = client.command("servo", closed)
        assert refused.error is not None and refused.error.code == 3204, refused
        assert "[0, 65]" in refused.error.message, refused.error
        below = client.command("inverted", m.MoveJoint(joint=6, angle_deg=-5.0))
        assert below.error is not None and below.error.code == 3204, below
        assert "[0, 100]" in below.error.message, below.error


# ----------------------------------------------------------------------------- interface


@pytest.mark.parametrize(
    "program", [["-m", "edge_agent", "--arm", "a1"], ["-m", "fleet.cli.main", "sim"]]
)
def test_an_interface_the_host_lacks_is_a_clear_error_not_a_crash(
    tmp_path: Path, program: list[str]
) -> None:
    """Before: CycloneDDS's "Non specific error" in a traceback. No DDS participant and no
    Zenoh session is opened: the interface is checked first."""
    inventory = tmp_path / "inventory.toml"
    inventory.write_text(
        '[fleet]\nname = "x"\n[arms.a1]\ninterface = "nosuch0"\nsimulated = true\n',
        encoding="utf-8",
    )
    done = subprocess.run(
        [sys.executable, *program, "--inventory", str(inventory)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    assert "network interface 'nosuch0' does not exist on this host" in done.stderr
    assert "Traceback" not in done.stderr, done.stderr
