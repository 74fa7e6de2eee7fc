"""Malformed choreography and inventory files: only the documented error comes out.

A choreography gives ``ScriptError`` and an inventory ``InventoryError`` (both name the file and
the path), whatever the file holds: a value of the wrong type in any field (int where a list is
expected, a list where a table is, a string or a bool where a number is), a huge integer (400 or
5000 digits), nesting thousands deep, bytes that are not UTF-8. What parses must also be usable:
the timeline and the validator run on the script, the contact detector is built from the
inventory, with no exception but the documented one. The CLI turns these into exit code 2 with
the message, never a traceback.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fleet.choreo.script import ScriptError, parse_script
from fleet.choreo.timeline import Timeline
from fleet.choreo.validate import check_motion
from fleet.contact.detector import ContactDetector
from fleet.inventory import InventoryError, load_inventory, parse_inventory
from testkit.file_tables import (
    CHOREO_FIELDS,
    INVENTORY_FIELDS,
    WHOLE_CHOREO_TABLES,
    choreo_text,
    inventory_text,
)

BIG = "1" + "0" * 400
HUGE = "1" * 5000  # past Python's 4300-digit limit for int(str)
DEEP = "[" * 3000 + "]" * 3000
ARMS = ["a1", "a2"]
GROUPS = {"left": ["a1"]}
ZERO = (0.0,) * 7

# ---------------------------------------------------------------------- choreography


def parse_choreo(text: str):  # type: ignore[no-untyped-def]
    return parse_script(text, "dance.toml", ARMS, GROUPS)


def use_script(text: str) -> None:
    """Parse, then run what `fleet play` runs before and while moving: only ScriptError."""
    try:
        script = parse_choreo(text)
    except ScriptError as exc:
        assert str(exc).startswith("dance.toml: "), exc
        return
    with contextlib.suppress(ScriptError):  # refused before moving: documented
        check_motion(script, dict.fromkeys(script.arms, ZERO))
    timeline = Timeline(script, dict.fromkeys(script.arms, ZERO))
    timeline.start(0.0)
    for now in (0.5, 1.0, 5.0, 50.0):
        timeline.tick(now, {})


def test_the_test_choreography_is_valid() -> None:
    script = parse_choreo(choreo_text({}))
    assert script.arms == ("a1", "a2") and script.loops == 2 and len(script.steps) == 2


# (overrides, fragment the message must contain)
BAD_CHOREOS = [
    ({"choreo.arms": "1"}, "choreo.arms"),
    ({"choreo.arms": '"a1"'}, "choreo.arms"),
    ({"choreo.arms": "[{x = 1}]"}, "choreo.arms"),
    ({"choreo.arms": "[[1]]"}, "choreo.arms"),
    ({"choreo": "1"}, "choreo"),
    ({"choreo": "[1, 2]"}, "choreo"),
    ({"choreo.name": "1"}, "choreo.name"),
    ({"choreo.name": "{a = 1}"}, "choreo.name"),
    ({"choreo.loops": BIG}, "choreo.loops"),
    ({"choreo.loops": "1e400"}, "choreo.loops"),
    ({"choreo.loops": '"2"'}, "choreo.loops"),
    ({"choreo.tolerance_deg": BIG}, "choreo.tolerance_deg"),
    ({"choreo.tolerance_deg": "-" + BIG}, "choreo.tolerance_deg"),
    ({"choreo.tolerance_deg": '"5"'}, "choreo.tolerance_deg"),
    ({"choreo.tolerance_deg": "true"}, "choreo.tolerance_deg"),
    ({"choreo.tolerance_deg": "[5]"}, "choreo.tolerance_deg"),
    ({"choreo.max_speed_deg_s": "nan"}, "choreo.max_speed_deg_s"),
    ({"choreo.start_lead_s": "1979-05-27T07:32:00Z"}, "choreo.start_lead_s"),
    ({"poses": "1"}, "poses"),
    ({"poses": "[1]"}, "poses"),
    ({"poses.up": "1"}, "poses.up"),
    ({"poses.up": "{a = 1}"}, "poses.up"),
    ({"poses.up": f"[{BIG}, 0, 0, 0, 0, 0, 0]"}, "poses.up[0]"),
    ({"poses.up": "[true, 0, 0, 0, 0, 0, 0]"}, "poses.up[0]"),
    ({"step": "1"}, "step"),
    ({"step": "[1]"}, "step[0]"),
    ({"step": '["wait"]'}, "step[0]"),
    ({"step": "[[1]]"}, "step[0]"),
    ({"step0.duration_s": BIG}, "step[0].duration_s"),
    ({"step0.duration_s": '"2"'}, "step[0].duration_s"),
    ({"step0.easing": "1"}, "step[0].easing"),
    ({"step0.easing": '["linear"]'}, "step[0].easing"),
    ({"step0.label": "1"}, "step[0].label"),
    ({"step0.label": "{a = 1}"}, "step[0].label"),
    ({"step0.all": "1"}, "step[0].all"),
    ({"step0.all": "{a = 1}"}, "step[0].all"),
    ({"step0.a1": "[[1], 0, 0, 0, 0, 0, 0]"}, "step[0].a1[0]"),
    ({"step1.wait": "1"}, "step[1].wait"),
    ({"step1.wait": "{a = 1}"}, "step[1].wait"),
    ({"step1.wait": "[1]"}, "step[1].wait"),
    ({"step1.arms": '"left"'}, "step[1].arms"),
    ({"step1.arms": "[[1]]"}, "step[1].arms"),
    ({"step1.arms": "[{a = 1}]"}, "step[1].arms"),
    ({"step1.timeout_s": BIG}, "step[1].timeout_s"),
    ({"step1.timeout_s": "false"}, "step[1].timeout_s"),
    ({"step1.label": "[1]"}, "step[1].label"),
]


@pytest.mark.parametrize(("overrides", "where"), BAD_CHOREOS, ids=lambda v: str(v)[:40])
def test_bad_choreography_fields_name_file_and_path(overrides: dict[str, str], where: str) -> None:
    with pytest.raises(ScriptError) as info:
        parse_choreo(choreo_text(overrides))
    message = str(info.value)
    assert message.startswith("dance.toml: ") and where in message, message
    assert len(message) < 400, "the message repeats a huge value"


@pytest.mark.parametrize(
    "text",
    [f"a = {HUGE}\n", f"a = {DEEP}\n", "a = " + "{b = " * 2000 + "1" + "}" * 2000 + "\n"],
    ids=["5000-digits", "deep-array", "deep-table"],
)
def test_toml_the_parser_chokes_on_is_a_script_error(text: str) -> None:
    with pytest.raises(ScriptError, match="^dance.toml: not valid TOML"):
        parse_choreo(text)


# ---------------------------------------------------------------------- inventory


def use_inventory(text: str) -> None:
    """Parse, then build what the agent builds from it: only InventoryError."""
    try:
        inventory = parse_inventory(text, "inv.toml")
    except InventoryError as exc:
        assert str(exc).startswith("inv.toml: "), exc
        return
    for arm in inventory.arms.values():
        ContactDetector(arm.contact)
        inventory.network_of([arm.id])


def test_the_test_inventory_is_valid() -> None:
    inventory = parse_inventory(inventory_text({}), "inv.toml")
    assert list(inventory.arms) == ["a1", "a2"] and inventory.groups == {"left": ["a1"]}


BAD_INVENTORIES = [
    ({"arms.a1.contact.buffer_size": BIG}, "buffer_size"),
    ({"arms.a1.contact.arm.oscillation_reversals": BIG}, "oscillation_reversals"),
    ({"arms.a1.watchdog_s": BIG}, "watchdog_s"),
    ({"defaults.watchdog_s": "1e400"}, "watchdog_s"),
    ({"arms.a1.domain_id": BIG}, "domain_id"),
    ({"dds.domain_id": BIG}, "domain_id"),
    ({"coordinator.heartbeat_hz": BIG}, "heartbeat_hz"),
    ({"arms.a1.base_xyz": f"[{BIG}, 0, 0]"}, "base_xyz"),
    ({"arms.a1.joint_sign": f"[{BIG}, 1, 1, 1, 1, 1, 1]"}, "joint_sign"),
    ({"arms.a1.lease_s": HUGE}, "not valid TOML"),
    ({"arms.a1.lease_s": DEEP}, "not valid TOML"),
    ({"arms.a1.contact.methods": "1"}, "methods"),
    ({"groups.left": "1"}, "groups"),
    ({"fleet.name": "[1]"}, "fleet.name"),
]


@pytest.mark.parametrize(("overrides", "where"), BAD_INVENTORIES, ids=lambda v: str(v)[:40])
def test_bad_inventory_fields_name_file_and_path(overrides: dict[str, str], where: str) -> None:
    with pytest.raises(InventoryError) as info:
        use_inventory_strict(inventory_text(overrides))
    message = str(info.value)
    assert message.startswith("inv.toml: ") and where in message, message
    assert len(message) < 400, "the message repeats a huge value"


def use_inventory_strict(text: str) -> None:
    """Like use_inventory, but the documented error propagates."""
    inventory = parse_inventory(text, "inv.toml")
    for arm in inventory.arms.values():
        ContactDetector(arm.contact)


def test_files_that_are_not_utf8_name_the_file(tmp_path: Path) -> None:
    inventory = tmp_path / "inv.toml"
    inventory.write_bytes(b'[fleet]\nname = "\xff"\n')
    with pytest.raises(InventoryError, match=f"^{inventory}: "):
        load_inventory(inventory)


# ---------------------------------------------------------------------- generated files


def _float_text(x: float) -> str:
    if x != x:
        return "nan"
    if x in (float("inf"), float("-inf")):
        return "inf" if x > 0 else "-inf"
    return repr(float(x))


SCALARS = st.one_of(
    st.integers().map(str),
    st.sampled_from([BIG, "-" + BIG, HUGE, "0", "-1", "1e400", "1979-05-27T07:32:00Z"]),
    st.floats().map(_float_text),
    st.booleans().map(lambda b: "true" if b else "false"),
    st.text(max_size=8).map(json.dumps),
    st.sampled_from(['"up"', '"all"', '"left"', '"a1"', '"reached"', '"linear"', '"stall"']),
)
KEYS = st.sampled_from(["a", "a1", "all", "wait", "x"])
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=8).map(lambda xs: "[" + ", ".join(xs) + "]"),
        st.dictionaries(KEYS, inner, max_size=3).map(
            lambda d: "{" + ", ".join(f"{k} = {v}" for k, v in d.items()) + "}"
        ),
    ),
    max_leaves=12,
)
FUZZ = settings(
    max_examples=400, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)


@FUZZ
@given(
    st.dictionaries(
        st.sampled_from([*CHOREO_FIELDS, *WHOLE_CHOREO_TABLES]), VALUES, min_size=1, max_size=3
    )
)
def test_generated_choreographies_give_only_script_errors(overrides: dict[str, str]) -> None:
    use_script(choreo_text(overrides))


@FUZZ
@given(st.dictionaries(st.sampled_from(list(INVENTORY_FIELDS)), VALUES, min_size=1, max_size=3))
def test_generated_inventories_give_only_inventory_errors(overrides: dict[str, str]) -> None:
    use_inventory(inventory_text(overrides))


# ---------------------------------------------------------------------- the CLI
