"""The stop actions that drop the arm, `unload` and `power_off`, end to end (real processes):
each is confirmed from the arm's own status (not from its ack, which the D1 is reported to send
for `power=0` while ignoring it), latched like `hold`, and `fleet estop` warns before it stops.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode
from testkit.harness import FleetHarness, wait_until

ARMS = """
[arms.a1]
suffix = "_1"
[arms.a2]
suffix = "_2"
stop_action = "unload"
[arms.a3]
suffix = "_3"
stop_action = "power_off"
"""


def test_unload_and_power_off_are_confirmed_from_status_and_latched(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=0, extra=ARMS) as h:
        client = h.start_fleet()
        estop = subprocess.run(
            [sys.executable, "-m", "fleet.cli.main", "estop", "--reason", "test"]
            + ["--inventory", str(h.inventory_path)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert estop.returncode == 0, estop.stdout + estop.stderr
        assert "a2's stop action is unload" in estop.stderr
        assert "a3's stop action is power_off" in estop.stderr
        assert "a1's stop action" not in estop.stderr
        assert "unloaded +" in estop.stdout and "unpowered +" in estop.stdout, estop.stdout
        statuses = {arm: s for arm, (s, _j) in client.snapshot().items()}
        assert all(s is not None and s.estopped for s in statuses.values()), statuses
        assert statuses["a2"] is not None and statuses["a2"].enabled is False
        assert statuses["a3"] is not None and statuses["a3"].powered is False
        for arm in ("a2", "a3"):  # latched: nothing brings them back but a reset
            for command in (m.Torque(on=True), m.Power(on=True), m.Zero()):
                reply = client.command(arm, command)
                assert reply.error is not None and reply.error.code == ErrorCode.REJECTED, reply
        client.reset()
        wait_until(
            lambda: all(s is not None and not s.estopped for s, _j in client.snapshot().values()),
            5.0,
        )
        assert client.command("a3", m.Power(on=True)).ok
        assert client.command("a2", m.Torque(on=True)).ok
