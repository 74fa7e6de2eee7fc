"""Choreography as pure code: parsing and its errors, limit and speed validation, the timeline
with an injected clock (easing, waits, loops, time left), grip confirmation, mirror mapping."""

from __future__ import annotations

import pytest

from fleet.choreo.grip import GripDetector
from fleet.choreo.script import Move, ScriptError, Wait, parse_script
from fleet.choreo.timeline import ArmFacts, PlayClock, Timeline, next_tick
from fleet.choreo.validate import check_motion
from fleet.teleop.mapping import MappingError, parse_mappings
from fleet.wire import messages as m

ARMS = ["a1", "a2", "a3"]
GROUPS = {"left": ["a1", "a2"]}
ZERO = (0.0,) * 7

DANCE = """
[choreo]
name = "t"
loops = 2

[poses]
up = [0, -30, 30, 0, 0, 0, 20]

[[step]]
duration_s = 2.0
easing = "linear"
all = "up"
a3 = [10, -30, 30, 0, 0, 0, 20]

[[step]]
wait = "reached"
arms = ["left"]
timeout_s = 1.0

[[step]]
duration_s = 1.0
left = [0, 0, 0, 0, 0, 0, 0]
"""


def parse(text: str = DANCE):  # type: ignore[no-untyped-def]
    return parse_script(text, "dance.toml", ARMS, GROUPS)


def test_parse_resolves_poses_groups_and_all() -> None:
    script = parse()
    assert script.arms == ("a1", "a2", "a3") and script.loops == 2
    first, wait, last = script.steps
    assert isinstance(first, Move) and isinstance(wait, Wait) and isinstance(last, Move)
    assert first.poses["a1"] == (0, -30, 30, 0, 0, 0, 20) and first.poses["a3"][0] == 10
    assert wait.arms == ("a1", "a2") and wait.condition == "reached"
    assert set(last.poses) == {"a1", "a2"} and last.easing == "ease_in_out"
    assert script.iteration_s == 3.0


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("a3 = [10, -30", "a3 = [10"), "dance.toml: step[0].a3: 7 angles expected"),
        (('easing = "linear"', 'easing = "bouncy"'), "step[0].easing: 'bouncy' is not one of"),
        (('all = "up"', 'all = "down"'), "step[0].all: unknown pose 'down'"),
        (("a3 = [", "a9 = ["), "step[0].a9: 'a9' is not an arm, a group or 'all'"),
        (('wait = "reached"', 'wait = "dance"'), "step[1].wait: 'dance' is not"),
        (("loops = 2", "loops = -1"), "choreo.loops"),
        (("duration_s = 2.0", "duration_s = 0"), "step[0].duration_s: 0 is outside"),
        (("timeout_s = 1.0", "timeout_s = 1.0\nspeed = 3"), "unknown field(s) in a wait step"),
    ],
)
def test_parse_errors_name_file_and_path(edit: tuple[str, str], message: str) -> None:
    with pytest.raises(ScriptError, match=None) as info:
        parse(DANCE.replace(*edit))
    assert message in str(info.value)


def test_validation_refuses_limits_and_speed_before_moving() -> None:
    bad = DANCE.replace("a3 = [10, -30", "a3 = [10, -95")
    with pytest.raises(ScriptError) as info:
        check_motion(parse(bad), dict.fromkeys(ARMS, ZERO))
    assert "step[0].a3 joint 1: -95 deg is outside -90..90" in str(info.value)
    # 100 deg in 1 s with ease_in_out peaks at 150 deg/s > 90: refused, from the start pose.
    fast = DANCE.replace('all = "up"', "all = [100, 0, 0, 0, 0, 0, 0]").replace(
        "duration_s = 2.0", "duration_s = 1.0"
    )
    with pytest.raises(ScriptError, match=r"step\[0\]\.a1 joint 0: \d+ deg/s peak"):
        check_motion(
            parse(fast.replace('easing = "linear"', 'easing = "ease_in_out"')),
            dict.fromkeys(ARMS, ZERO),
        )  # noqa: E501
    # The loop's wrap-around (last pose -> first keyframe) is checked too.
    start = dict.fromkeys(ARMS, (0.0, -30.0, 30.0, 0.0, 0.0, 0.0, 20.0))
    check_motion(parse(), start)


def test_timeline_interpolates_with_easing_and_exact_step_times() -> None:
    script = parse()
    timeline = Timeline(script, dict.fromkeys(ARMS, ZERO))
    timeline.start(100.0)
    frame = timeline.tick(101.0, {})
    assert frame.kind == "move" and frame.step_index == 0
    assert frame.targets["a1"][1] == pytest.approx(-15.0)  # linear, half way
    assert frame.step_left_s == pytest.approx(1.0) and frame.total_left_s == pytest.approx(5.0)
    reached = {a: ArmFacts(angles_deg=timeline.script.steps[0].poses[a]) for a in ARMS}  # type: ignore[union-attr]
    frame = timeline.tick(102.05, reached)  # keyframe 0 done, the wait is satisfied at once
    assert frame.finished_keyframes == [0] and frame.step_index == 2
    assert frame.targets["a1"][1] == -30.0  # the next move starts when the wait was satisfied
    assert timeline.tick(102.55, {}).targets["a1"][1] == pytest.approx(-15.0)  # smoothstep
    frame = timeline.tick(103.5, {})  # second pass, step 0 again (the move ended at 103.05)
    assert frame.iteration == 1 and frame.step_index == 0
    assert frame.targets["a1"][1] == pytest.approx(-30.0 * 0.45 / 2.0)
    assert frame.targets["a3"][0] == 10.0
    frame = timeline.tick(105.05, reached)
    frame = timeline.tick(106.2, {})
    assert frame.kind == "done" and frame.total_left_s == 0.0
    assert frame.targets["a1"] == ZERO and frame.targets["a3"][0] == 10.0


def test_wait_times_out_with_the_reason() -> None:
    timeline = Timeline(parse(), dict.fromkeys(ARMS, ZERO))
    timeline.start(0.0)
    timeline.tick(2.0, {})  # in the wait now
    far = {"a1": ArmFacts(angles_deg=ZERO), "a2": ArmFacts()}
    frame = timeline.tick(2.5, far)
    assert frame.kind == "wait" and frame.label == "step 1"
    frame = timeline.tick(3.1, far)
    assert frame.kind == "failed"
    assert frame.error is not None and "a1 (30.0 deg off)" in frame.error
    assert "a2 (no angles)" in frame.error


def test_grip_wait_and_detector() -> None:
    text = DANCE.replace('wait = "reached"', 'wait = "grip"').replace("loops = 2", "loops = 1")
    timeline = Timeline(parse(text), dict.fromkeys(ARMS, ZERO))
    timeline.start(0.0)
    timeline.tick(2.0, {})
    gripped = {"a1": ArmFacts(gripped=True), "a2": ArmFacts(gripped=True)}
    assert timeline.tick(2.1, gripped).step_index == 2

    detector = GripDetector()
    for angle in (30.0, 20.0, 12.0):  # closing towards 0
        detector.add([0, 0, 0, 0, 0, 0, angle])
    assert not detector.gripped(0.0)
    for angle in (12.1, 12.0, 12.05):  # stopped 12 deg short: an object
        detector.add([0, 0, 0, 0, 0, 0, angle])
    assert detector.gripped(0.0) and not detector.gripped(11.0)


def test_loops_forever_has_no_end() -> None:
    timeline = Timeline(parse(DANCE.replace("loops = 2", "loops = 0")), dict.fromkeys(ARMS, ZERO))
    timeline.start(0.0)
    assert timeline.tick(0.5, {}).total_left_s is None


def test_mirror_mapping_inverts_and_clamps() -> None:
    a2, a3 = parse_mappings(["a2", "a3"], ["a2:0,5"], ["a3:1=-20:20"])
    leader = [10.0, -40.0, 5.0, 0.0, 0.0, 30.0, 20.0]
    assert a2.apply(leader) == [-10.0, -40.0, 5.0, 0.0, 0.0, -30.0, 20.0]
    assert a3.apply(leader)[1] == -20.0
    assert a2.apply([200.0, 0, 0, 0, 0, 0, 99.0])[0] == -135.0
    with pytest.raises(MappingError, match="inside joint 1's range"):
        parse_mappings(["a2"], [], ["a2:1=-100:0"])
    with pytest.raises(MappingError, match="followers are"):
        parse_mappings(["a2"], ["a9:1"])


def test_stop_messages_used_by_the_player_exist() -> None:
    assert m.MoveJoints(angles_deg=list(ZERO), mode=0, stamp_ns=1, lifetime_s=0.3).mode == 0


def test_a_leader_cannot_follow_itself() -> None:
    """``fleet mirror --leader a1 --follower a1`` left a1 unloaded and commanded at once."""
    from fleet.teleop.mirror import Mirror

    with pytest.raises(MappingError, match="cannot follow itself"):
        Mirror(None, "a1", parse_mappings(["a2", "a1"]))  # type: ignore[arg-type]


def test_a_stalled_player_skips_the_ticks_it_missed_and_its_timeline_holds() -> None:
    # 10 Hz ticks; the player wakes for tick 5 (due 0.5 s) at 0.83 s: a 0.33 s stall.
    assert next_tick(5, 0.83, 0.1) == 9  # the next tick still ahead, never 6, 7, 8 at once
    assert next_tick(5, 0.51, 0.1) == 6  # on time: the next one
    clock = PlayClock(0.1)
    assert clock.play_time(0.4, 0.43) == 0.43  # late by less than a period: as is
    assert clock.play_time(0.5, 0.83) == 0.5  # resumes where the late tick was due
    assert clock.play_time(0.9, 0.9) == pytest.approx(0.57)  # and goes on from there
    assert clock.lost_s == pytest.approx(0.33)
