"""Choreography files (``fleet play dance.toml``): parse and validate. Pure: no I/O but the text.

A script is a list of steps played in order by every arm involved, from one synchronized start:

- a **move** step (a keyframe): ``duration_s``, ``easing`` and, per arm, the absolute pose
  (seven angles in degrees, wire ids 0..6, or the name of a ``[poses]`` entry) the arm reaches
  at the end of the step. Keys may be an arm id, a group of the inventory, ``all`` (every D1
  arm) or a G1's arm, ``h1.left`` / ``h1.right`` (``fleet/choreo/g1_arms.py``); an arm the
  step does not name keeps its previous keyframe;
- a **wait** step: ``wait = "reached"`` (the arms are within ``reach_tolerance_deg`` of their
  current keyframe) or ``wait = "grip"`` (the arms' grippers confirmed a grip), on ``arms``
  (default: every arm involved; for a grip, every D1 arm involved: a G1 arm has no gripper),
  for at most ``timeout_s`` (then the script aborts).

``[choreo]`` sets ``loops`` (1; 0 = until stopped), ``tolerance_deg`` (path tolerance while
playing), ``reach_tolerance_deg``, ``max_speed_deg_s`` and ``start_lead_s``. Errors name the
file and the path: ``dance.toml: step[2].a1: 7 angles expected, got 6``.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, cast

from fleet.choreo.g1_arms import SIDES, arm_name, is_g1_arm, split
from fleet.d1.limits import JOINT_COUNT
from fleet.tomlfile import TomlError, brief, decode_toml

Easing = Literal["linear", "ease_in", "ease_out", "ease_in_out"]
EASINGS: tuple[str, ...] = ("linear", "ease_in", "ease_out", "ease_in_out")
Condition = Literal["reached", "grip"]
Pose = tuple[float, ...]

HARD_MAX_SPEED_DEG_S = 180.0
"""No script may ask more of a joint than this (the simulated arm's mode-0 speed limit)."""
MAX_LOOPS = 1_000_000
"""More passes than anyone plays (``loops = 0`` plays forever); a file's 400-digit count would
overflow the timeline's time-left arithmetic (int times float)."""

_MOVE_KEYS = {"duration_s", "easing", "label"}
_WAIT_KEYS = {"wait", "arms", "timeout_s", "label"}
_CHOREO_KEYS = {
    "name",
    "arms",
    "loops",
    "tolerance_deg",
    "reach_tolerance_deg",
    "max_speed_deg_s",
    "start_lead_s",
}


class ScriptError(ValueError):
    """A choreography that cannot be played; the message names the file and the path."""


@dataclass(frozen=True)
class Move:
    """A keyframe: each arm of ``poses`` reaches its pose ``duration_s`` after the step starts."""

    duration_s: float
    easing: Easing
    poses: Mapping[str, Pose]
    label: str = ""


@dataclass(frozen=True)
class Wait:
    """Hold every pose until ``condition`` holds for ``arms`` (at most ``timeout_s``)."""

    condition: Condition
    arms: tuple[str, ...]
    timeout_s: float
    label: str = ""


Step = Move | Wait


@dataclass(frozen=True)
class Script:
    """A validated choreography (limits are checked again against the start poses by
    ``check_motion`` before anything moves)."""

    name: str
    arms: tuple[str, ...]
    steps: tuple[Step, ...]
    loops: int = 1
    tolerance_deg: float = 10.0
    reach_tolerance_deg: float = 3.0
    max_speed_deg_s: float = 90.0
    start_lead_s: float = 0.5
    source: str = field(default="<script>", compare=False)

    @property
    def moves(self) -> list[Move]:
        """The move steps, in order."""
        return [s for s in self.steps if isinstance(s, Move)]

    @property
    def iteration_s(self) -> float:
        """The time one pass takes without its waits."""
        return sum(m.duration_s for m in self.moves)


def _fail(source: str, where: str, why: str) -> ScriptError:
    return ScriptError(f"{source}: {where}: {why}" if where else f"{source}: {why}")


def _number(value: Any, source: str, where: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(source, where, f"a number expected, got {brief(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer of more than ~308 digits
        number = math.inf if value > 0 else -math.inf
    if not (math.isfinite(number) and low <= number <= high):
        raise _fail(source, where, f"{brief(value)} is outside {low:g}..{high:g}")
    return number


def _table(value: Any, source: str, where: str) -> Mapping[str, Any]:
    if not isinstance(value, dict):
        raise _fail(source, where, f"a table expected, got {brief(value)}")
    return value


def _text(value: Any, source: str, where: str) -> str:
    if not isinstance(value, str):
        raise _fail(source, where, f"a string expected, got {brief(value)}")
    return value


def _names(value: Any, source: str, where: str) -> list[str]:
    """A list of arm or group names (strings)."""
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise _fail(source, where, f"a list of arms or groups expected, got {brief(value)}")
    return value


def _pose(value: Any, poses: Mapping[str, Pose], source: str, where: str) -> Pose:
    if isinstance(value, str):
        if value not in poses:
            known = ", ".join(sorted(poses)) or "none defined"
            raise _fail(source, where, f"unknown pose {value!r} (poses: {known})")
        return poses[value]
    if not isinstance(value, list) or len(value) != JOINT_COUNT:
        raise _fail(source, where, f"{JOINT_COUNT} angles expected, got {brief(value)}")
    return tuple(_number(v, source, f"{where}[{i}]", -1e6, 1e6) for i, v in enumerate(value))


def _resolve(
    target: str,
    arms: Sequence[str],
    groups: Mapping[str, Sequence[str]],
    source: str,
    where: str,
    g1s: Sequence[str] = (),
) -> list[str]:
    """The arms ``target`` names: ``all`` (every D1 arm), a group, an arm, a G1 arm
    (``h1.left``) or a G1 (both its arms)."""
    if target == "all":
        return list(arms)
    if target in groups:
        return list(groups[target])
    if target in arms:
        return [target]
    if target in g1s:
        return [arm_name(target, side) for side in SIDES]
    parts = split(target)
    if parts is not None and parts[0] in g1s:
        return [target]
    g1_hint = f"; G1 arms: {', '.join(arm_name(g, s) for g in g1s for s in SIDES)}" if g1s else ""
    raise _fail(
        source,
        where,
        f"{target!r} is not an arm, a group or 'all' (arms: {list(arms)}{g1_hint})",
    )


def _g1_targets(
    raw: Mapping[str, Any], g1s: Sequence[str], source: str, where: str
) -> dict[str, Any]:
    """A step's keys with a G1's table (``h1.left = ...`` is TOML for ``h1 = {left = ...}``)
    flattened to ``h1.left``; a G1 named without its side is refused."""
    flat: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in g1s and isinstance(value, dict):
            known = ", ".join(g1s) or "none"
            why = (
                f"{key!r} is not a G1 of the inventory (G1s: {known}): only a G1's arms are "
                "named <g1>.left / <g1>.right"
            )
            raise _fail(source, f"{where}.{key}", why)
        if key not in g1s:
            flat[key] = value
            continue
        sides = ", ".join(arm_name(key, s) for s in SIDES)
        if not isinstance(value, dict):
            why = f"{key!r} is a G1: name one of its arms ({sides})"
            raise _fail(source, f"{where}.{key}", why)
        for side, pose in value.items():
            if side not in SIDES:
                why = f"a G1's arms are {sides}; {arm_name(key, side)!r} is none of them"
                raise _fail(source, f"{where}.{key}.{side}", why)
            flat[arm_name(key, side)] = pose
    return flat


def _unknown_field(key: str, fields: set[str], what: str) -> str:
    """Name the unknown field, the valid ones and, for a typo, the one meant."""
    guess = difflib.get_close_matches(key, sorted(fields), n=1)
    hint = f"; did you mean {guess[0]!r}?" if guess else ""
    valid = ", ".join(sorted(fields))
    if what == "a move step":
        valid += ", and arms, groups or `all` as targets"
    return f"unknown field(s) in {what}: {key!r} (its fields: {valid}){hint}"


def _move(
    raw: Mapping[str, Any],
    arms: Sequence[str],
    groups: Mapping[str, Sequence[str]],
    poses: Mapping[str, Pose],
    source: str,
    where: str,
    g1s: Sequence[str] = (),
) -> Move:
    raw = _g1_targets(raw, g1s, source, where)
    targets_known = {"all", *groups, *arms, *(arm_name(g, s) for g in g1s for s in SIDES)}
    for key in raw:
        typo = difflib.get_close_matches(key, sorted(_MOVE_KEYS), n=1)
        if key not in _MOVE_KEYS and key not in targets_known and typo:
            # A misspelt field, not an arm: say so (it would read "not an arm" or, taken as a
            # target, complain about its value).
            raise _fail(source, f"{where}.{key}", _unknown_field(key, _MOVE_KEYS, "a move step"))
    duration = _number(raw.get("duration_s"), source, f"{where}.duration_s", 0.1, 3600.0)
    easing = raw.get("easing", "ease_in_out")
    if not isinstance(easing, str) or easing not in EASINGS:
        why = f"{brief(easing)} is not one of {', '.join(EASINGS)}"
        raise _fail(source, f"{where}.easing", why)
    targets: dict[str, Pose] = {}
    # "all" first, then groups, then arms: the most specific entry wins.
    order = sorted(
        (k for k in raw if k not in _MOVE_KEYS),
        key=lambda k: 0 if k == "all" else 1 if k in groups else 2,
    )
    for key in order:
        pose = _pose(raw[key], poses, source, f"{where}.{key}")
        for arm in _resolve(key, arms, groups, source, f"{where}.{key}", g1s):
            targets[arm] = pose
    if not targets:
        raise _fail(source, where, "a move step names no arm (give `a1 = [...]` or `all = ...`)")
    label = _text(raw.get("label", ""), source, f"{where}.label")
    return Move(duration, cast(Easing, easing), targets, label)


def _wait(
    raw: Mapping[str, Any],
    arms: Sequence[str],
    groups: Mapping[str, Sequence[str]],
    source: str,
    where: str,
    involved: Sequence[str],
    g1s: Sequence[str] = (),
) -> Wait:
    for key in sorted(set(raw) - _WAIT_KEYS):
        raise _fail(source, f"{where}.{key}", _unknown_field(key, _WAIT_KEYS, "a wait step"))
    condition = raw["wait"]
    if not isinstance(condition, str) or condition not in ("reached", "grip"):
        raise _fail(source, f"{where}.wait", f"{brief(condition)} is not 'reached' or 'grip'")
    default = [a for a in involved if condition == "reached" or not is_g1_arm(a)]
    if "arms" not in raw and not default:
        why = "a grip wait needs a D1 arm (a G1 arm has no gripper); this script moves none"
        raise _fail(source, f"{where}.wait", why)
    names = _names(raw.get("arms", default), source, f"{where}.arms")
    if not names:
        raise _fail(source, f"{where}.arms", "a non-empty list of arms or groups expected")
    waited: list[str] = []
    for name in names:
        waited += _resolve(name, arms, groups, source, f"{where}.arms", g1s)
    for arm in waited:
        if condition == "grip" and is_g1_arm(arm):
            why = (
                f"{arm!r} is a G1 arm: it has no gripper (its joint 6 is the wrist's yaw), so "
                "no grip can be confirmed on it; wait for a grip on D1 arms only, or use "
                'wait = "reached"'
            )
            raise _fail(source, f"{where}.arms", why)
        if arm not in involved:
            why = f"{arm!r} moves in no step (name it in a move step or in [choreo] arms)"
            raise _fail(source, f"{where}.arms", why)
    timeout = _number(raw.get("timeout_s", 10.0), source, f"{where}.timeout_s", 0.1, 600.0)
    label = _text(raw.get("label", ""), source, f"{where}.label")
    return Wait(cast(Condition, condition), tuple(dict.fromkeys(waited)), timeout, label)


def parse_script(
    text: str,
    source: str = "<script>",
    arms: Sequence[str] = (),
    groups: Mapping[str, Sequence[str]] | None = None,
    g1s: Sequence[str] = (),
) -> Script:
    """Parse a choreography TOML against the inventory's ``arms``, ``groups`` and G1s
    (``g1s``: their ids; their arms are ``<id>.left`` / ``<id>.right``)."""
    groups = dict(groups or {})
    try:
        raw = decode_toml(text)
    except TomlError as exc:
        raise _fail(source, "", str(exc)) from None
    unknown = set(raw) - {"choreo", "poses", "step"}
    if unknown:
        raise _fail(source, "", f"unknown table(s) {', '.join(sorted(unknown))}")
    head = _table(raw.get("choreo", {}), source, "choreo")
    for key in sorted(set(head) - _CHOREO_KEYS):
        raise _fail(source, f"choreo.{key}", _unknown_field(key, _CHOREO_KEYS, "[choreo]"))
    raw_poses = _table(raw.get("poses", {}), source, "poses")
    poses = {k: _pose(v, {}, source, f"poses.{k}") for k, v in raw_poses.items()}
    raw_steps = raw.get("step", [])
    if not isinstance(raw_steps, list) or not raw_steps:
        raise _fail(source, "step", "no [[step]] tables: a script needs at least one move")
    tables = [_table(step, source, f"step[{i}]") for i, step in enumerate(raw_steps)]
    moves: list[tuple[int, Move]] = []
    for i, step in enumerate(tables):
        if "wait" not in step:
            moves.append((i, _move(step, arms, groups, poses, source, f"step[{i}]", g1s)))
    involved = list(dict.fromkeys(a for _i, mv in moves for a in mv.poses))
    for name in _names(head.get("arms", []), source, "choreo.arms"):
        for arm in _resolve(name, arms, groups, source, "choreo.arms", g1s):
            if arm not in involved:
                involved.append(arm)
    if not moves:
        raise _fail(source, "step", "no move step: nothing would move")
    by_index = dict(moves)
    steps: list[Step] = [
        by_index[i]
        if i in by_index
        else _wait(s, arms, groups, source, f"step[{i}]", involved, g1s)
        for i, s in enumerate(tables)
    ]
    loops = head.get("loops", 1)
    if isinstance(loops, bool) or not isinstance(loops, int) or not 0 <= loops <= MAX_LOOPS:
        why = f"a whole number 0..{MAX_LOOPS} expected (0 = forever), got {brief(loops)}"
        raise _fail(source, "choreo.loops", why)

    def setting(key: str, default: float, low: float, high: float) -> float:
        return _number(head.get(key, default), source, f"choreo.{key}", low, high)

    return Script(
        name=_text(head.get("name", source), source, "choreo.name"),
        arms=tuple(involved),
        steps=tuple(steps),
        loops=loops,
        tolerance_deg=setting("tolerance_deg", 10.0, 0.5, 90.0),
        reach_tolerance_deg=setting("reach_tolerance_deg", 3.0, 0.1, 45.0),
        max_speed_deg_s=setting("max_speed_deg_s", 90.0, 1.0, HARD_MAX_SPEED_DEG_S),
        start_lead_s=setting("start_lead_s", 0.5, 0.1, 4.0),
        source=source,
    )
