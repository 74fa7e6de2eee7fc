"""The viewer's kept token (fleet/web/token_store.py): the same token after a restart for one
fleet, a file only its owner can read, a leaked or broken file replaced, never the token in
the log, and a token per run where nothing can be kept."""

from __future__ import annotations

import logging
import os
import stat
from pathlib import Path

import pytest

from fleet.web.access import check_token
from fleet.web.token_store import token_path, viewer_token


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_the_token_is_kept_per_fleet_readable_by_its_owner_only(tmp_path: Path) -> None:
    first = viewer_token("lab", tmp_path)
    assert check_token(first) == first
    assert viewer_token("lab", tmp_path) == first  # a restart: the open tabs keep working
    assert viewer_token("other", tmp_path) != first
    path = token_path("lab", tmp_path)
    assert _mode(path) == 0o600 and _mode(path.parent) & 0o077 == 0
    assert [p.name for p in path.parent.iterdir()] == ["viewer.token"]  # no temporary left
    renewed = viewer_token("lab", tmp_path, renew=True)
    assert renewed != first and viewer_token("lab", tmp_path) == renewed


def test_the_state_directory_comes_from_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("D1_FLEET_STATE_DIR", str(tmp_path / "state"))
    token = viewer_token("lab")
    assert (tmp_path / "state" / "lab" / "viewer.token").read_text().strip() == token


@pytest.mark.parametrize(
    ("content", "mode", "why"),
    [
        ("t0ken-that-others-could-read_0123", 0o644, "readable by others"),
        ("short", 0o600, "no usable token"),
        ("x" * 300, 0o600, "no usable token"),
    ],
)
def test_a_leaked_or_broken_file_is_replaced_and_the_token_never_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, content: str, mode: int, why: str
) -> None:
    path = token_path("lab", tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text(content)
    path.chmod(mode)
    with caplog.at_level(logging.DEBUG, logger="fleet.web.token_store"):
        token = viewer_token("lab", tmp_path)
    assert token != content and check_token(token) == token
    assert _mode(path) == 0o600 and path.read_text().strip() == token
    assert why in caplog.text
    assert token not in caplog.text and content not in caplog.text


def test_a_link_in_place_of_the_file_is_not_followed(tmp_path: Path) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.write_text("t0ken-from-somewhere-else_0123")
    path = token_path("lab", tmp_path)
    path.parent.mkdir(parents=True)
    path.symlink_to(elsewhere)
    token = viewer_token("lab", tmp_path)
    assert token != "t0ken-from-somewhere-else_0123"
    assert not path.is_symlink() and _mode(path) == 0o600
    assert elsewhere.read_text() == "t0ken-from-somewhere-else_0123"  # untouched


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_where_nothing_can_be_kept_the_token_is_for_this_run(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    tmp_path.chmod(0o500)
    try:
        with caplog.at_level(logging.WARNING, logger="fleet.web.token_store"):
            first, second = viewer_token("lab", tmp_path), viewer_token("lab", tmp_path)
    finally:
        tmp_path.chmod(0o700)
    assert first != second and check_token(first) == first
    assert "for this run only" in caplog.text and first not in caplog.text
