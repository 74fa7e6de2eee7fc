"""A G1's arms in a choreography, as pure code: how a script names them (``h1.left``), what it
refuses (a G1 without its side, a grip on a G1 arm, a joint outside the G1's own limits or
faster than its own speed limit), and the one rt/arm_sdk target both arms and the waist make."""

from __future__ import annotations

import math

import pytest

from fleet.choreo import g1_arms
from fleet.choreo.script import Move, ScriptError, Wait, parse_script
from fleet.choreo.timeline import ArmFacts, Timeline
from fleet.choreo.validate import check_motion
from fleet.g1 import arms

ARMS = ["a1", "a2"]
G1S = ["h1"]
ZERO = (0.0,) * 7

DANCE = """
[choreo]
name = "g1"

[poses]
down = [0, 0, 0, 0, 0, 0, 0]

[[step]]
duration_s = 2.0
all = [0, -30, 45, 0, 30, 0, 30]
h1.left = [0, 40, 45, 0, 0, 0, 0]
"h1.right" = [0, -40, -45, 0, 0, 0, 0]

[[step]]
wait = "reached"

[[step]]
wait = "grip"

[[step]]
duration_s = 2.0
a1 = [0, 0, 0, 0, 0, 0, 30]
h1 = { left = "down" }
"""


def parse(text: str = DANCE):  # type: ignore[no-untyped-def]
    return parse_script(text, "dance.toml", ARMS, {"pair": ARMS}, G1S)


def test_g1_arms_are_named_beside_d1_arms_and_all_means_the_d1_arms() -> None:
    script = parse()
    assert script.arms == ("a1", "a2", "h1.left", "h1.right")
    first, reached, grip, last = script.steps
    assert isinstance(first, Move) and isinstance(last, Move)
    assert first.poses["h1.left"] == (0, 40, 45, 0, 0, 0, 0)
    assert first.poses["h1.right"][1] == -40  # the quoted key reads the same
    assert set(last.poses) == {"a1", "h1.left"} and last.poses["h1.left"] == ZERO
    # `reached` waits for every arm involved; a grip only for the D1 arms (the G1 has none)
    assert isinstance(reached, Wait) and reached.arms == script.arms
    assert isinstance(grip, Wait) and grip.arms == ("a1", "a2")


@pytest.mark.parametrize(
    ("edit", "where", "why"),
    [
        (("h1.left = [0, 40", "h1 = [0, 40"), "step[0].h1", "is a G1: name one of its arms"),
        (("h1.left = [0, 40", "h1.up = [0, 40"), "step[0].h1.up", "is none of them"),
        (("h1.left = [0, 40", "h2.left = [0, 40"), "step[0].h2", "is not a G1 of the inventory"),
        (('"h1.right"', '"h2.right"'), "step[0].h2.right", "is not an arm, a group or 'all'"),
        (("h1.left = [0, 40, 45", "h1.left = [0, 40"), "step[0].h1.left", "7 angles expected"),
        (
            ('wait = "grip"', 'wait = "grip"\narms = ["a1", "h1.left"]'),
            "step[2].arms",
            "'h1.left' is a G1 arm: it has no gripper",
        ),
        (
            ('wait = "grip"', 'wait = "grip"\narms = ["h1"]'),
            "step[2].arms",
            "'h1.left' is a G1 arm: it has no gripper",
        ),
    ],
)
def test_bad_g1_names_are_refused_naming_the_step(
    edit: tuple[str, str], where: str, why: str
) -> None:
    assert edit[0] in DANCE
    with pytest.raises(ScriptError) as error:
        parse(DANCE.replace(*edit))
    assert str(error.value).startswith(f"dance.toml: {where}: "), error.value
    assert why in str(error.value), error.value


def test_a_grip_wait_in_a_g1_only_script_says_why() -> None:
    text = "[[step]]\nduration_s = 1.0\nh1.left = [0, 10, 0, 0, 0, 0, 0]\n[[step]]\nwait = 'grip'\n"
    with pytest.raises(ScriptError, match=r"step\[1\].wait: a grip wait needs a D1 arm"):
        parse(text)


def test_a_wait_on_an_arm_that_never_moves_is_refused() -> None:
    text = "[[step]]\nduration_s = 1.0\na1 = [0, 0, 0, 0, 0, 0, 30]\n"
    text += "[[step]]\nwait = 'reached'\narms = ['h1.right']\n"
    with pytest.raises(ScriptError, match=r"step\[1\].arms: 'h1.right' moves in no step"):
        parse(text)


def test_g1_joints_are_checked_against_the_g1s_own_limits() -> None:
    start = dict.fromkeys(("a1", "a2", "h1.left", "h1.right"), ZERO)
    # The G1's right shoulder roll reaches +1.5882 rad (91 deg, towards its body), its left one
    # +2.2515 rad (129 deg, away from it): 100 deg is outside the one, inside the other.
    bad = DANCE.replace('"h1.right" = [0, -40', '"h1.right" = [0, 100')
    with pytest.raises(ScriptError) as error:
        check_motion(parse(bad), start)
    assert "step[0].h1.right joint 1: 100 deg is outside -129.001..90.9972" in str(error.value)
    fine = DANCE.replace("h1.left = [0, 40", "h1.left = [0, 100").replace(
        "duration_s = 2.0", "duration_s = 3.0", 1
    )
    check_motion(parse(fine), start)


def test_g1_speed_is_capped_by_its_own_limit() -> None:
    start = dict.fromkeys(("a1", "a2", "h1.left", "h1.right"), ZERO)
    script = parse(DANCE.replace("[choreo]", "[choreo]\nmax_speed_deg_s = 150.0"))
    # h1.left's shoulder yaw: 45 deg in 2 s, eased (peak 1.5x the average): 34 deg/s
    check_motion(script, start, None, {"h1.left": 60.0})
    with pytest.raises(ScriptError) as error:
        check_motion(script, start, None, {"h1.left": 30.0})
    assert "step[0].h1.left joint 2: 34 deg/s peak" in str(error.value)
    assert "exceeds 30 deg/s (h1.left's own limit)" in str(error.value)


def test_one_target_holds_the_waist_and_the_unnamed_arm() -> None:
    held = [0.01 * i for i in range(arms.COUNT)]
    q = g1_arms.target_rad(held, {"right": (10, 20, 30, 40, 50, 60, 70)})
    assert q[:10] == held[:10]  # the waist and the left arm as measured
    assert q[10:] == pytest.approx([math.radians(a) for a in (10, 20, 30, 40, 50, 60, 70)])
    low = [0.0] * arms.MOTORS
    low[arms.FIRST + 3] = math.radians(12.0)  # left shoulder pitch
    assert g1_arms.side_pose_deg(low, "left")[0] == pytest.approx(12.0)
    assert g1_arms.split("h1.left") == ("h1", "left") and g1_arms.split("a1") is None
    assert g1_arms.devices_of(["a1", "h1.right", "h1.left"]) == {"h1": ["right", "left"]}


def test_the_timeline_waits_for_a_g1_arm_to_reach_its_keyframe() -> None:
    script = parse(DANCE.replace('wait = "grip"', 'wait = "reached"'))
    start = dict.fromkeys(script.arms, ZERO)
    timeline = Timeline(script, start)
    timeline.start(0.0)
    goal = script.steps[0].poses  # type: ignore[union-attr]
    there = {a: ArmFacts(goal[a]) for a in script.arms}
    lagging = {**there, "h1.left": ArmFacts(ZERO)}
    assert timeline.tick(2.05, lagging).kind == "wait"
    assert "h1.left (45.0 deg off)" in (timeline.tick(13.0, lagging).error or "")
