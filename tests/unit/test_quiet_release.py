"""Issue 26 item 7: a release of a robot held by nobody is done, not refused (the demo's player
releases after every stop of its dance, and a stop ends every lease), and ``fleet diag`` shows a
last error whole, wrapped at word boundaries, never cut mid-sentence."""

from __future__ import annotations

import pytest

from fleet.cli.wire_tools import diag_lines
from fleet.devices.driver import Refusal
from fleet.devices.envelope import release
from fleet.devices.safety import ArmSafety
from fleet.wire import messages as m


def test_releasing_a_robot_nobody_holds_is_done_quietly() -> None:
    safety = ArmSafety(lease_s=3.0, watchdog_s=0.5)
    safety.check_owner("player", False, 0.0)  # the player takes the arm
    assert safety.latch("s1", "viewer", "", 1.0, 1)  # a stop ends every lease
    release("arm 'a1'", safety, "player", 1.1)  # the player's release after the stop: fine
    safety.reset()
    safety.check_owner("alice", False, 2.0)
    with pytest.raises(Refusal, match="arm 'a1' is held by alice"):
        release("arm 'a1'", safety, "player", 2.1)  # someone else holds it: refused
    release("arm 'a1'", safety, "player", 2.0 + 3.5)  # alice's lease expired: nobody holds it
    with pytest.raises(Refusal, match="names its owner"):
        release("arm 'a1'", safety, None, 6.0)


def test_diag_shows_the_last_error_whole_and_wrapped() -> None:
    error = (
        "refused 2 commands: arm 'a1' is held by alice: its lease expires in 2.5 s unless "
        "renewed. To take the arm anyway: --takeover on the command line, takeover=True in "
        "the API; the last one at 12:00:01"
    )
    diag = m.Diag(
        stamp_ns=1,
        link="ok",
        relayed=1,
        malformed=0,
        unknown_messages=0,
        unknown_fields=0,
        rejected=2,
        commands=3,
        ack_timeouts=0,
        feedback_rate_hz=100.0,
        last_feedback_age_s=0.01,
        last_error=error,
    )
    lines = diag_lines(["a1"], {"a1": diag}, columns=80)
    below = lines[2:]
    assert len(below) > 1 and all(len(line) <= 80 for line in below)
    assert " ".join(line.strip() for line in below) == f"last error: {error}"
