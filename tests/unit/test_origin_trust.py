"""The one trust policy of arms and devices (``fleet/origin/trust.py``), with injected writer
handles, hosts and clock: whose samples count, and which readings are possible."""

from __future__ import annotations

import pytest

from fleet.origin.trust import OriginFilter, SampleWriter, SpeedCheck

HOST = "dex1-1 udp/192.168.123.110"
ROGUE = "laptop udp/192.168.123.50"
WINDOW_S = 0.5


def _filter() -> OriginFilter:
    return OriginFilter("gripper 'gl'", WINDOW_S)


def test_the_first_writer_of_a_state_topic_owns_it_while_it_speaks() -> None:
    origins, own, beside = _filter(), SampleWriter(7, HOST), SampleWriter(8, HOST)
    assert origins.refusal(own, "rt/dex1/left/state", True, 0.0) is None
    why = origins.refusal(beside, "rt/dex1/left/state", True, 0.01)
    assert why is not None and "second writer" in why and "gripper 'gl'" in why
    assert "rogue participant" in why
    assert origins.refusal(own, "rt/dex1/left/state", True, 0.4) is None
    # Another topic of the same robot has its own first writer on the host.
    assert origins.refusal(beside, "rt/lowstate", True, 0.41) is None
    # Silent for the window: a restarted service (a new writer) takes the topic over.
    assert origins.refusal(beside, "rt/dex1/left/state", True, 0.4 + WINDOW_S + 0.01) is None
    assert origins.refusal(own, "rt/dex1/left/state", True, 0.4 + WINDOW_S + 0.02) is not None


def test_another_host_is_foreign_until_the_robot_was_silent_for_the_window() -> None:
    origins = _filter()
    assert origins.refusal(SampleWriter(7, HOST), "state", True, 0.0) is None
    rogue = SampleWriter(11, ROGUE)
    why = origins.refusal(rogue, "state", True, 0.1)
    assert why is not None and ROGUE in why and HOST in why
    # Non-periodic messages (a D1's acks) from another host are foreign too ...
    assert origins.refusal(rogue, "ack", False, 0.2) is not None
    # ... but from any writer on the robot's host they count.
    assert origins.refusal(SampleWriter(9, HOST), "ack", False, 0.3) is None
    # A replaced robot (another host) takes over once the old one was silent for the window.
    assert origins.refusal(rogue, "state", True, 0.3 + WINDOW_S + 0.01) is None
    assert origins.refusal(SampleWriter(7, HOST), "state", True, 0.9) is not None


def test_a_rogue_flood_never_takes_over_while_the_robot_speaks() -> None:
    """Foreign samples never refresh the anchor: only the robot's own keep it."""
    origins, own, rogue = _filter(), SampleWriter(7, HOST), SampleWriter(11, ROGUE)
    for i in range(40):  # 2 s: four windows, the robot speaking every 50 ms
        assert origins.refusal(own, "state", True, i * 0.05) is None
        assert origins.refusal(rogue, "state", True, i * 0.05 + 0.01) is not None
    # A robot silent for the window loses its anchor: the next writer heard is trusted (the
    # price of following a replaced robot; its link went stale meanwhile).
    assert origins.refusal(rogue, "state", True, 1.95 + WINDOW_S + 0.01) is None


def test_writers_of_no_named_host_are_one_group_and_an_unknown_writer_is_trusted() -> None:
    origins = _filter()
    assert origins.refusal(SampleWriter(7, None), "state", True, 0.0) is None
    assert origins.refusal(SampleWriter(8, None), "state", True, 0.1) is not None
    assert origins.refusal(SampleWriter(8, HOST), "ack", False, 0.1) is not None
    assert origins.refusal(None, "state", True, 0.2) is None


def _speed(reanchor: int = 3) -> SpeedCheck:
    return SpeedCheck("gripper 'gl'", 20.0, "rad", 0.002, 0.05, reanchor)


def test_a_position_faster_than_the_device_moves_is_dropped() -> None:
    check = _speed()
    assert check.refusal((6.28,), 0.0) is None
    assert check.refusal((6.26,), 0.002) is None  # 10 rad/s: possible
    why = check.refusal((0.0,), 0.004)  # forged "fully closed": 3000 rad/s
    assert why is not None and "faster than 20 rad/s" in why and "gripper 'gl'" in why
    assert check.last == (6.26,)
    # Reports read in one batch at the same time are still a period apart.
    assert check.refusal((6.22,), 0.004) is None
    # After a long gap the limit grows with the time.
    assert check.refusal((3.0,), 1.0) is None


def test_a_jump_that_persists_is_followed_after_a_few_agreeing_readings() -> None:
    check = _speed(reanchor=3)
    assert check.refusal((6.28,), 0.0) is None
    assert check.refusal((1.0,), 0.002) is not None
    assert check.refusal((1.0,), 0.004) is not None
    assert check.refusal((1.0,), 0.006) is None and check.last == (1.0,)


def test_alternating_forged_and_real_readings_never_reanchor() -> None:
    check = _speed(reanchor=3)
    assert check.refusal((6.28,), 0.0) is None
    for i in range(1, 30):
        forged = check.refusal((0.0,), i * 0.004)
        assert forged is not None
        assert check.refusal((6.28,), i * 0.004 + 0.002) is None
    assert check.last == (6.28,)


@pytest.mark.parametrize("joint", range(7))
def test_the_arms_rule_is_per_joint(joint: int) -> None:
    check = SpeedCheck("arm 'a1'", 360.0, "deg", 0.1, 2.0, 3)
    home = (0.0,) * 7
    assert check.refusal(home, 0.0) is None
    jumped = tuple(80.0 if i == joint else 0.0 for i in range(7))
    why = check.refusal(jumped, 0.1)
    assert why is not None and "jumped 80 deg" in why
