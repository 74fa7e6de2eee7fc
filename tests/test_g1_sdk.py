"""Unitree's own SDK (tests/sdk_g1.py) as the far side of the G1, on real CycloneDDS (loopback,
the test's own domain) and real Zenoh:

- its ``LocoClient`` drives our simulated G1 on both service names (``sport`` for ai_sport >=
  8.2, ``loco`` before): walk, the dynamic-state refusal, continuous gait (StopMove alone keeps
  it stepping, ContinuousGait(false) ends it), damp;
- a fake G1 built on its RPC ``Server`` is stopped by ``fleet estop`` through our agent while
  walking in continuous gait, on both names (and ``auto``), confirmed from its sportmodestate
  within 1 s; with no sportmodestate at all (firmware before 1.5.1) damp still reaches it.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest
import unitree_sdk2py  # noqa: F401 - `make` installs it (--no-deps): a missing SDK fails, never skips

from fleet.g1.kind import KIND
from fleet.g1.messages import ContinuousGait, Damp, G1State, SetVelocity, StandUp
from fleet.wire import keys
from tests.harness import FleetHarness, wait_until
from tests.test_dex1_end_to_end import agent_token
from tests.test_end_to_end import Collector

STATE = KIND.payloads[keys.STATE]
CONFIRM_GOAL_S = 1.0
"""Issue 22: a stop of a walking G1 confirmed within 1 s, on both service names."""


def _sdk(harness: FleetHarness, name: str, *argv: str) -> subprocess.Popen[bytes]:
    args = ["-m", "tests.sdk_g1", *argv, "--domain", str(harness.domain)]
    return harness.start(name, args, inventory=False)


def _calls(harness: FleetHarness, name: str) -> list[dict]:
    return [
        json.loads(line) for line in harness.log(name).splitlines() if line.startswith('{"api_id"')
    ]


@pytest.mark.parametrize("service", ["sport", "loco"])
def test_unitree_loco_client_drives_our_simulator(tmp_path, service: str) -> None:  # type: ignore[no-untyped-def]
    extra = f'[g1.h1]\nsim_service = "{service}"\nsim_settle_s = 0.3\n'
    with FleetHarness(tmp_path, arms=1, extra=extra) as harness:
        harness.start_router()
        harness.start_sim()
        client = _sdk(harness, "sdk-client", "client", "--service", service)
        try:
            client.wait(timeout=60)
        except subprocess.TimeoutExpired:
            pytest.fail(f"the SDK's client did not finish:\n{harness.log('sdk-client')}")
        lines = [x for x in harness.log("sdk-client").splitlines() if x.startswith('{"service"')]
        assert client.returncode == 0 and lines, harness.log("sdk-client")
        out = json.loads(lines[-1])
    assert out["service"] == service
    assert out["state_s"] is not None
    assert out["get_fsm_id"] == [0, '{"data": 500}']
    assert out["walk"] == 0 and out["walk_dynamic_s"] is not None
    assert out["stand_up_while_dynamic"] == 3205  # seed 004: no mode switch while dynamic
    assert out["continuous_on"] == 0 and out["balance_mode"] == [0, '{"data": 1}']
    assert out["stop_move"] == 0
    assert out["static_after_stop_move_s"] is None, out  # continuous gait keeps stepping
    assert out["continuous_off"] == 0  # allowed while dynamic: the way out
    assert out["static_after_continuous_off_s"] is not None, out
    assert out["damp"] == 0 and out["damped_s"] is not None
    assert out["set_task_id"] == 3203  # an API our simulator does not implement
    print(f"LocoClient on {service!r}: {out}")


def _fleet(tmp_path, service: str, setting: str, action: str, *flags: str) -> FleetHarness:  # type: ignore[no-untyped-def]
    extra = (
        f'[g1.h1]\nsimulated = false\nservice = "{setting}"\nstop_action = "{action}"\n'
        "max_duration_s = 5.0\n"
    )
    harness = FleetHarness(tmp_path, arms=1, extra=extra)
    harness.start_router()
    server = _sdk(harness, "fake-g1", "server", "--service", service, *flags)
    wait_until(lambda: '"ready"' in harness.log("fake-g1") or server.poll() is not None, 30.0)
    assert server.poll() is None, harness.log("fake-g1")
    harness.start("devices", ["-m", "edge_agent", "--device", "h1"])
    return harness


@pytest.fixture
def closing() -> Iterator[list[FleetHarness]]:
    harnesses: list[FleetHarness] = []
    yield harnesses
    for harness in harnesses:
        harness.close()


@pytest.mark.parametrize(
    ("service", "setting"), [("sport", "sport"), ("loco", "loco"), ("loco", "auto")]
)
def test_fleet_estop_stops_a_fake_g1_on_unitrees_server(
    tmp_path,  # type: ignore[no-untyped-def]
    closing: list[FleetHarness],
    service: str,
    setting: str,
) -> None:
    harness = _fleet(tmp_path, service, setting, "stop_move")
    closing.append(harness)
    client = harness.client()
    key = keys.KeySpace(harness.inventory.fleet).device("g1", "h1", keys.STATE)
    states: Collector[G1State] = Collector(client.session, key, STATE.decode)
    try:
        wait_until(lambda: (s := states.latest()) is not None and s.service_answered, 30.0)
        wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)
        first = states.latest()
        assert first is not None and (first.service, first.service_setting) == (service, setting)
        # Walking, in continuous gait (it would keep stepping at zero velocity).
        assert client.device_command("h1", SetVelocity(vx=0.3, duration_s=5.0)).ok
        assert client.device_command("h1", ContinuousGait(on=True)).ok
        wait_until(lambda: (s := states.latest()) is not None and s.mode == "dynamic", 3.0)
        before = len(_calls(harness, "fake-g1"))
        cli = [sys.executable, "-m", "fleet.cli.main", "estop", "h1", "--timeout", "3"]
        done = subprocess.run(
            [*cli, "--inventory", str(harness.inventory_path)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0, (done.stdout, done.stderr, harness.log("devices")[-2000:])
        line = next(x for x in done.stdout.splitlines() if x.startswith("g1/h1:"))
        match = re.search(r"confirmed \+([\d.]+) ms", line)
        assert match is not None, line
        confirmed_s = float(match.group(1)) / 1000
        print(f"fleet estop of a walking G1 (continuous gait), service {setting!r}: {line}")
        assert confirmed_s <= CONFIRM_GOAL_S, line
        # What reached the robot, each write in order: StopMove, then ContinuousGait(false)
        # (both delivered through the SDK server's request reader, depth 1 by its defaults).
        calls = [(c["api_id"], c["parameter"], c["code"]) for c in _calls(harness, "fake-g1")]
        stop_move = (7105, '{"velocity": [0.0, 0.0, 0.0], "duration": 1.0}', 0)
        assert calls[before : before + 2] == [stop_move, (7102, '{"data": 0}', 0)], calls
        latest = states.latest()
        assert latest is not None and latest.mode == "static" and latest.fsm_id == 500
    finally:
        states.close()


def test_damp_reaches_a_g1_without_state(tmp_path, closing: list[FleetHarness]) -> None:  # type: ignore[no-untyped-def]
    """Firmware before 1.5.1: no rt/sportmodestate. Damp is never refused for it; a damp stop
    is written, reported ``unconfirmed: no state`` and repeated until reset."""
    harness = _fleet(tmp_path, "sport", "sport", "damp", "--no-state")
    closing.append(harness)
    client = harness.client()
    wait_until(lambda: agent_token(client, "g1", "h1"), 30.0)

    def damps() -> int:
        return sum(
            c["api_id"] == 7101 and c["parameter"] == '{"data": 1}'
            for c in _calls(harness, "fake-g1")
        )

    reply = client.device_command("h1", Damp())
    assert reply.ok, reply  # the robot answered 0
    assert damps() == 1
    start = time.monotonic()
    acks = client.estop(timeout_s=1.0)
    ack = acks["g1/h1"]
    assert ack is not None and not ack.done and ack.dds_written_ns is not None, acks
    assert ack.detail is not None and ack.detail.startswith("unconfirmed: no state"), ack
    # Repeated (every 0.2 s) while unconfirmed ...
    wait_until(lambda: damps() >= 4, 3.0)
    print(f"damp stop without state: {damps() - 1} writes in {time.monotonic() - start:.2f} s")
    # ... until the operator resets: then no more.
    client.reset()

    def released() -> bool:  # refused now for the missing state, no longer for the stop
        error = client.device_command("h1", StandUp()).error
        return error is not None and "no fresh" in error.message

    wait_until(released, 5.0)
    after = damps()
    with pytest.raises(AssertionError):  # three repeat periods without one (one in flight)
        wait_until(lambda: damps() > after + 1, 0.6)
