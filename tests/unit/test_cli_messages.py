"""The command line's small promises: one line where a traceback was, and messages that say
what to type (issue 15's first-use defects)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from fleet.choreo.script import ScriptError, parse_script
from fleet.cli.main import build_parser, main
from fleet.devices.safety import LeaseRefused
from fleet.inventory import InventoryError, parse_inventory

REPO = Path(__file__).resolve().parents[2]
F_SETPIPE_SZ = 1031


def test_version_and_plain_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.startswith("fleet ")
    assert "``" not in build_parser().format_help(), "reStructuredText backticks in --help"


def test_a_non_finite_angle_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["move", "a1", "--angles", "nan", "0", "0", "0", "0", "0", "0"])
    assert done.value.code == 2
    assert "not a finite number" in capsys.readouterr().err


def test_the_lease_message_says_what_to_type() -> None:
    text = str(LeaseRefused("operator/ann", 2.5))
    assert "--takeover" in text and "takeover=True" in text
    assert "renewed. To take" in text, "two sentences run together"


@pytest.mark.parametrize(("typo", "meant"), [("duraton_s", "duration_s"), ("eazing", "easing")])
def test_a_choreography_typo_is_named_with_the_field_meant(typo: str, meant: str) -> None:
    text = (REPO / "choreo" / "demo.toml").read_text()
    assert meant in text
    with pytest.raises(ScriptError) as error:
        parse_script(text.replace(meant, typo, 1), "demo.toml", ["a1", "a2", "a3"], g1s=["h1"])
    assert f"unknown field(s) in a move step: {typo!r}" in str(error.value)
    assert f"did you mean {meant!r}" in str(error.value)


def test_a_bad_stop_action_lists_the_valid_ones() -> None:
    text = (
        (REPO / "inventory.toml")
        .read_text()
        .replace("[arms.a1]", '[arms.a1]\nstop_action = "halt"', 1)
    )
    with pytest.raises(InventoryError, match="one of: hold, unload, power_off"):
        parse_inventory(text)


def _subcommand(name: str) -> argparse.ArgumentParser:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices[name]


def test_the_cli_reference_names_every_option_of_the_demo_and_replay_says_where_it_goes() -> None:
    """The CLI table missed `--port`, `--dance`, `--foxglove` of `fleet demo`; `fleet replay`'s
    help said "into the viewer" though it publishes on `<fleet>-replay`. (Every command's options:
    tests/test_docs.py.)"""
    cli = Path(__file__).resolve().parents[2] / "docs" / "guide" / "cli.md"
    text = cli.read_text(encoding="utf-8")
    shown = text.split("### `fleet demo`", 1)[1].split("\n### ", 1)[0]
    common = {"--inventory", "--endpoint", "--domain", "--log-level", "--log-file", "--log-format"}
    common |= {"--help", "--connect-timeout", "--principal"}
    options = {
        option
        for action in _subcommand("demo")._actions
        for option in action.option_strings
        if option.startswith("--")
    }
    missing = sorted(o for o in options - common if f"`{o}" not in shown)
    assert missing == [], f"docs/guide/cli.md's fleet demo section lacks {missing}"
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    help_text = next(c.help for c in action._choices_actions if c.dest == "replay")
    assert "into the viewer" not in help_text and "-replay" in help_text, help_text
