"""Where the D1 spec reads two ways, both readings work: the pure parts (issue 13).

The end-to-end tests of both readings on the simulator are in ``test_readings_e2e.py``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from fleet.d1 import dds
from fleet.d1 import protocol as p
from fleet.d1.errors import InvalidCommand, NetworkInterfaceError
from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.d1.topics import MAX_SUFFIX
from fleet.d1arm.acks import AckMatcher, ExecTimeouts
from fleet.inventory import InventoryError, parse_inventory

# ----------------------------------------------------------------------------- ack seq


def test_an_echoed_seq_matches_its_command_whatever_the_order() -> None:
    acks = AckMatcher(recv_timeout_s=0.5, exec_timeout_s=2.0)
    acks.written(1, now=0.0)
    acks.written(2, now=0.0)
    assert acks.answered(p.ReceiveAck(2, True), now=0.1) == (2, "seq")
    assert acks.answered(p.ReceiveAck(1, True), now=0.1) == (1, "seq")
    assert acks.answered(p.ExecuteAck(1, True), now=0.1) == (1, "seq")


def test_seq_10_answers_the_oldest_command_awaiting_that_kind_of_ack() -> None:
    acks = AckMatcher(recv_timeout_s=0.5, exec_timeout_s=2.0)
    acks.written(1, now=0.0)
    acks.written(2, now=0.01)
    assert acks.answered(p.ReceiveAck(10, True), now=0.1) == (1, "oldest")
    assert acks.answered(p.ReceiveAck(10, True), now=0.1) == (2, "oldest")
    assert acks.answered(p.ExecuteAck(10, True), now=0.1) == (1, "oldest")
    assert acks.answered(p.ExecuteAck(10, True), now=0.1) == (2, "oldest")
    assert acks.answered(p.ExecuteAck(10, True), now=0.1) == (None, "none")


def test_a_refused_command_expects_no_execute_ack() -> None:
    """recv_status 0: the arm will not execute it, so the next execute ack is the next one's."""
    acks = AckMatcher(recv_timeout_s=0.5, exec_timeout_s=2.0)
    acks.written(1, now=0.0)
    acks.written(2, now=0.0)
    assert acks.answered(p.ReceiveAck(10, False), now=0.1) == (1, "oldest")
    assert acks.answered(p.ReceiveAck(10, True), now=0.1) == (2, "oldest")
    assert acks.answered(p.ExecuteAck(10, True), now=0.1) == (2, "oldest")


def test_an_overdue_command_no_longer_takes_a_seq_10_ack() -> None:
    """A lost ack shifts the attribution only until the lost one's command expires."""
    acks = AckMatcher(recv_timeout_s=0.5, exec_timeout_s=2.0)
    acks.written(1, now=0.0)
    acks.written(2, now=0.6)
    assert acks.answered(p.ReceiveAck(10, True), now=0.7) == (2, "oldest")


def test_a_late_echoed_ack_is_ignored_not_credited_to_another_command() -> None:
    acks = AckMatcher(recv_timeout_s=0.5, exec_timeout_s=2.0)
    acks.written(1, now=0.0)
    acks.written(2, now=0.6)
    assert acks.answered(p.ReceiveAck(1, True), now=0.7) == (None, "late")
    assert acks.answered(p.ReceiveAck(1, True), now=0.7) == (None, "late")
    assert acks.answered(p.ReceiveAck(2, True), now=0.7) == (2, "seq")
    assert acks.answered(p.ReceiveAck(2, True), now=0.7) == (None, "late")  # repeated


def test_an_ack_whose_seq_is_neither_ours_nor_10_is_foreign_never_credited() -> None:
    """Before: any seq but ours answered our oldest command (another client's command on the
    arm's topic, acked with its own seq, completed ours)."""
    acks = AckMatcher(recv_timeout_s=0.5, exec_timeout_s=2.0)
    acks.written(1, now=0.0)
    assert acks.answered(p.ExecuteAck(4242, False), now=0.1) == (None, "foreign")
    assert acks.answered(p.ReceiveAck(4, True), now=0.1) == (None, "foreign")
    assert acks.awaiting() == (1, 1)
    assert acks.answered(p.ExecuteAck(10, True), now=0.1) == (1, "oldest")


def test_the_execute_ack_timeout_is_per_op() -> None:
    """A return to zero or a long move may be "executed" only once the motion finished."""
    timeouts = ExecTimeouts(2.0, {"torque": 3.0})
    assert timeouts.of(p.ReturnToZero()) == 10.0
    assert timeouts.of(p.SetJointAngle(0, 90.0)) == 5.0
    assert timeouts.of(p.SetAllTorque(1)) == 3.0  # the arm's own table
    assert timeouts.of(p.SetPower(True)) == 2.0 and timeouts.of(None) == 2.0
    assert ExecTimeouts(12.0).of(p.ReturnToZero()) == 12.0  # never less than the default
    hold_then_enable = (p.SetAllAngles((0.0,) * 7, 0), p.SetAllTorque(1))
    assert timeouts.longest(hold_then_enable) == 5.0
    acks = AckMatcher(recv_timeout_s=0.5, exec_timeout_s=timeouts)
    acks.written(1, now=0.0, command=p.ReturnToZero())
    acks.written(2, now=0.0, command=p.SetPower(True))
    # At 4 s the power's execute ack is overdue, the zero's is not: seq 10 answers the zero.
    assert acks.answered(p.ExecuteAck(10, True), now=4.0) == (1, "oldest")
    assert acks.answered(p.ExecuteAck(2, True), now=4.0) == (None, "late")


def test_the_per_op_table_is_checked_and_merged_over_the_defaults() -> None:
    inventory = parse_inventory(
        BASE + "[defaults]\nexec_ack_timeouts = {zero = 20.0, power = 4.0}\n"
        "[arms.a1]\nexec_ack_timeouts = {zero = 30.0}\n"
    )
    assert inventory.arm("a1").exec_ack_timeouts == {"zero": 30.0, "power": 4.0}
    for bad, words in (("{fly = 1.0}", "unknown op 'fly'"), ("{zero = 0.0}", "0..600")):
        with pytest.raises(InventoryError, match=words):
            parse_inventory(BASE + f"[arms.a1]\nexec_ack_timeouts = {bad}\n")


def test_the_tables_are_bounded_when_the_arm_never_answers() -> None:
    acks = AckMatcher(recv_timeout_s=1e9, exec_timeout_s=1e9)
    for seq in range(1, 5000):
        acks.written(seq, now=0.0)
    assert max(acks.awaiting()) <= 256


# ----------------------------------------------------------------------------- inventory

BASE = '[fleet]\nname = "lab"\n'


@pytest.mark.parametrize("suffix", ["", "_1", "1", "-a", ".left", "/x", "::arm", "a" * MAX_SUFFIX])
def test_any_suffix_that_makes_a_legal_dds_topic_is_accepted(suffix: str) -> None:
    inventory = parse_inventory(BASE + f'[arms.a1]\nsuffix = "{suffix}"\n')
    assert inventory.arm("a1").suffix == suffix


@pytest.mark.parametrize("suffix", ["a b", "$", "#1", "*", "?", "[1]", "'", "é", "a" * 242])
def test_a_suffix_that_makes_no_legal_dds_topic_is_refused(suffix: str) -> None:
    with pytest.raises(InventoryError, match="arms.a1: suffix .* legal DDS topic name"):
        parse_inventory(BASE + f'[arms.a1]\nsuffix = "{suffix}"\n')


def test_empty_interface_and_multicast_are_inventory_choices() -> None:
    inventory = parse_inventory(BASE + '[arms.a1]\ninterface = ""\nmulticast = true\npeers = []\n')
    network = inventory.network_of(["a1"])
    assert (network.interface, network.peers, network.multicast) == ("", (), True)


def test_arms_with_and_without_multicast_need_two_processes() -> None:
    inventory = parse_inventory(
        BASE + '[arms.a1]\nsuffix = "_1"\n[arms.a2]\nsuffix = "_2"\nmulticast = true\n'
    )
    with pytest.raises(InventoryError, match="one process per network"):
        inventory.network_of(["a1", "a2"])


@pytest.mark.parametrize(
    ("line", "fragment"),
    [
        ('sim_ack_seq = "ten"', "one of: echo, fixed"),
        ("sim_error_status = 1", "sim_error_status 1 is the normal value"),
    ],
)
def test_simulator_readings_are_checked(line: str, fragment: str) -> None:
    with pytest.raises(InventoryError, match=fragment):
        parse_inventory(BASE + f"[arms.a1]\n{line}\n")


# ----------------------------------------------------------------------------- DDS config


def test_unicast_config_binds_the_interface_with_multicast_off() -> None:
    root = ET.fromstring(dds.cyclonedds_config("eth1", ["192.168.123.100"]))
    assert [e.get("name") for e in root.iter("NetworkInterface")] == ["eth1"]
    assert root.findtext("Domain/General/AllowMulticast") == "false"
    assert [e.get("address") for e in root.iter("Peer")] == ["192.168.123.100"]


def test_empty_interface_and_multicast_config_is_what_the_unitree_sdk_does() -> None:
    """No interface: CycloneDDS chooses one; multicast discovery on. (Generated only: a test
    never joins a multicast network, which would reach every other test's arms.)"""
    root = ET.fromstring(dds.cyclonedds_config("", [], multicast=True))
    assert list(root.iter("NetworkInterface")) == []
    assert list(root.iter("Interfaces")) == []
    assert root.findtext("Domain/General/AllowMulticast") == "default"


def test_an_interface_the_host_lacks_is_named_in_a_clear_error() -> None:
    """CycloneDDS only says "Non specific error"; no participant is created."""
    with pytest.raises(NetworkInterfaceError, match="'nosuch0' does not exist on this host"):
        dds.DdsChannel(1, "nosuch0")


# ----------------------------------------------------------------------------- gripper unit


def test_gripper_reading_is_per_arm_and_defaults_to_servo_degrees_closed_at_0() -> None:
    inventory = parse_inventory(
        BASE + '[arms.a1]\nsuffix = "_1"\n'
        '[arms.a2]\nsuffix = "_2"\ngripper_closed_deg = 100.0\ngripper_open_deg = 0.0\n'
    )
    a1, a2 = inventory.arm("a1"), inventory.arm("a2")
    assert a1.joint_ranges_deg == JOINT_RANGE_DEG and a1.gripper_closing_sign == -1.0
    assert a2.joint_ranges_deg[:6] == JOINT_RANGE_DEG[:6]
    assert a2.joint_ranges_deg[6] == (0.0, 100.0) and a2.gripper_closing_sign == 1.0
    p.check_angle(6, 90.0, a2.joint_ranges_deg)
    with pytest.raises(InvalidCommand, match="outside its range"):
        p.check_angle(6, 90.0, a1.joint_ranges_deg)
    with pytest.raises(InvalidCommand, match=r"\[0, 100\]"):
        p.encode_command(p.SetJointAngle(6, 101.0), 4, a2.joint_ranges_deg)


@pytest.mark.parametrize(
    "line", ["gripper_closed_deg = 5.0\ngripper_open_deg = 5.5", "gripper_open_deg = 400.0"]
)
def test_a_gripper_reading_without_a_stroke_is_refused(line: str) -> None:
    with pytest.raises(InventoryError, match="arms.a1: gripper_closed_deg"):
        parse_inventory(BASE + f"[arms.a1]\n{line}\n")


def test_viewer_draws_each_arms_gripper_its_own_way() -> None:
    """Closed fingers (0.033 m) at the arm's closed reading, open (0 m) at its open one."""
    from fleet.scene3d.kinematics import FINGER_TRAVEL_M, wire_to_q

    angles = [[0.0] * 6 + [g] for g in (0.0, 65.0, 100.0, 0.0)]
    gripper = [(0.0, 65.0), (0.0, 65.0), (100.0, 0.0), (100.0, 0.0)]
    q = wire_to_q(angles, [1] * 7, gripper)
    assert q[:, 6].tolist() == pytest.approx([FINGER_TRAVEL_M, 0.0, FINGER_TRAVEL_M, 0.0])


def test_grip_logic_knows_which_way_closing_is() -> None:
    from fleet.choreo.grip import GripDetector
    from fleet.choreo.player import path_error_deg

    default, inverted = GripDetector(), GripDetector(closing_sign=1.0)
    for _ in range(10):
        default.add([0.0] * 6 + [30.0])  # stopped at 30 on its way to 10: holds something
        inverted.add([0.0] * 6 + [70.0])  # stopped at 70 on its way to 90: holds something
    assert default.gripped(10.0) and inverted.gripped(90.0)
    assert not inverted.gripped(50.0)  # went further than asked: not a grip
    target = (0.0,) * 6 + (90.0,)
    assert path_error_deg((0.0,) * 6 + (70.0,), target, closing_sign=1.0) == 0.0  # a grip
    assert path_error_deg((0.0,) * 6 + (95.0,), target, closing_sign=1.0) == 5.0  # past it
