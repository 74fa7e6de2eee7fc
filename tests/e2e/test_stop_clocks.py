"""No sender's clock switches the stop off, once per kind (D1 arm, Dex1-1 gripper, G1): one
agent serving all three on one card, their simulators, a router; real DDS and Zenoh.

A reset stamped far ahead of the agent's clock (``2**63-1``, a host 30 s ahead) is refused,
said in its ``reset/ack`` and counted, and every later stop still latches; a stop stamped 0, 5 s
behind or 30 s ahead latches and a reset releases it; ``fleet reset`` from a host 30 s ahead
says that each unit is still stopped, and why, instead of "reset sent"."""

from __future__ import annotations

import subprocess
import sys
import time
import uuid
from collections.abc import Iterator

import pytest

from fleet.client import FleetClient
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, encode
from fleet.wire.payloads import DIAG, RESET_ACK
from fleet.wire.stoppath import RELIABLE_QOS
from testkit.collect import Collector
from testkit.harness import FleetHarness, wait_until
from testkit.kinds import (
    KIND_IDS,
    KINDS,
    Kind,
    LatchWatch,
    devices_fleet,
    release,
    send,
    wait_kinds_online,
    with_envelope,
)

NS = 10**9
FAR_AHEAD = {"30s-ahead": 30 * NS, "max": None}
"""How far ahead of the agent's clock a bad stamp is (None: the largest stamp, 2**63-1)."""


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FleetHarness]:
    with devices_fleet(tmp_path_factory.mktemp("clocks")) as harness:
        wait_kinds_online(harness)
        yield harness


@pytest.fixture
def client(fleet: FleetHarness) -> Iterator[FleetClient]:
    client = fleet.client()
    yield client
    client.reset()  # every test leaves every unit unlatched


def _stamp(ahead_ns: int | None) -> int:
    return 2**63 - 1 if ahead_ns is None else time.time_ns() + ahead_ns


def _released(client: FleetClient, kind: Kind) -> LatchWatch:
    """The unit's latch watch once a reset released it (it reports unlatched)."""
    watch = LatchWatch(client, kind)
    client.reset_and_report(kind.unit)
    wait_until(lambda: watch.link_ok() and watch.estopped() is False, 15.0)
    return watch


def _stopped(client: FleetClient, kind: Kind, stamp_ns: int | None = None) -> str:
    """Stop the unit (stamped ``stamp_ns``, else now) and wait for its ack; the stop's id."""
    request = client.stop_request("clock test", source="test")
    if stamp_ns is not None:
        request = m.StopRequest(stamp_ns, request.source, request.stop_id, request.reason)
    client.put_stop(request, kind.unit)
    acks = client.estop(kind.unit, request=request, timeout_s=10.0, wait_still=False)
    ack = acks[kind.label(client)]
    assert ack is not None and ack.stop_id == request.stop_id, f"{kind.name}: no ack: {acks}"
    return request.stop_id


def _reset_ack(client: FleetClient, kind: Kind, key: str, stamp_ns: int) -> m.ResetAck:
    """Put a reset stamped ``stamp_ns`` on ``key`` and wait for the unit's answer."""
    reset_id = uuid.uuid4().hex
    answers = Collector(
        client.session, client.unit_key(kind.unit, keys.RESET_ACK), RESET_ACK.decode
    )
    request = m.ResetRequest(stamp_ns=stamp_ns, source="skewed", reset_id=reset_id)
    try:
        client.session.put(key, encode(request), **RELIABLE_QOS)
        wait_until(lambda: any(a.reset_id == reset_id for a in answers.items), 10.0)
        return next(a for a in answers.items if a.reset_id == reset_id)
    finally:
        answers.close()


def _bad_stamps(diags: Collector[m.Diag]) -> int:
    """The agent's count of far-future stamps in its newest diag (-1 before one came)."""
    diag = diags.latest()
    return -1 if diag is None else diag.bad_stamps


@pytest.mark.parametrize("ahead", list(FAR_AHEAD.values()), ids=list(FAR_AHEAD))
@pytest.mark.parametrize("kind", KINDS, ids=KIND_IDS)
def test_a_reset_stamped_far_ahead_is_refused_and_every_later_stop_latches(
    client: FleetClient, kind: Kind, ahead: int | None
) -> None:
    """Before: one reset stamped 2**63-1 on the fleet's key made every later stop ignored (an
    arm finished its move through ``fleet estop``); a host 30 s ahead did it for 30 s."""
    watch = _released(client, kind)
    diags = Collector(client.session, client.unit_key(kind.unit, keys.DIAG), DIAG.decode)
    wait_until(lambda: _bad_stamps(diags) >= 0, 10.0)
    counted = _bad_stamps(diags)
    _stopped(client, kind)
    wait_until(lambda: watch.estopped() is True, 10.0)
    refused = _reset_ack(client, kind, client.keys.reset, _stamp(ahead))
    assert refused.outcome == "refused", refused
    assert "ahead of this agent's clock" in refused.detail, refused
    time.sleep(0.6)  # a window: a released unit reports it within 0.25 s (status at 4 Hz)
    assert watch.estopped() is True, "a refused reset released the stop"
    # Stops after it: the fleet's, as `fleet estop` puts them, and the unit's own.
    client.reset_and_report(kind.unit)
    wait_until(lambda: watch.estopped() is False, 10.0)
    acks = client.estop(None, reason="after a future reset", timeout_s=10.0)
    assert acks[kind.label(client)] is not None, f"{kind.name}: the fleet's stop ignored"
    wait_until(lambda: watch.estopped() is True, 10.0)
    answers = client.reset_and_report(kind.unit)
    assert answers[kind.label(client)] is not None
    assert answers[kind.label(client)].outcome == "released", answers  # type: ignore[union-attr]
    wait_until(lambda: watch.estopped() is False, 10.0)
    _stopped(client, kind)
    wait_until(lambda: watch.estopped() is True, 10.0)
    wait_until(lambda: _bad_stamps(diags) > counted, 10.0)
    diags.close()


STOP_STAMPS = {"zero": lambda: 0, "5s-behind": lambda: time.time_ns() - 5 * NS}
STOP_STAMPS |= {name: (lambda a=a: _stamp(a)) for name, a in FAR_AHEAD.items()}


@pytest.mark.parametrize("stamp", list(STOP_STAMPS.values()), ids=list(STOP_STAMPS))
@pytest.mark.parametrize("kind", KINDS, ids=KIND_IDS)
def test_a_stop_latches_whatever_its_stamp_and_a_reset_releases_it(
    client: FleetClient, kind: Kind, stamp: object
) -> None:
    """Before: a stop stamped 0 or from a host 5 s behind was dropped after any reset (on
    every kind), and a stop from a host ahead could not be reset until that host's time."""
    watch = _released(client, kind)
    _stopped(client, kind, stamp())  # type: ignore[operator]
    wait_until(lambda: watch.estopped() is True, 10.0)
    answers = client.reset_and_report(kind.unit)
    answer = answers[kind.label(client)]
    assert answer is not None and answer.outcome == "released", answers
    wait_until(lambda: watch.estopped() is False, 10.0)


def test_fleet_reset_from_a_host_30s_ahead_says_each_unit_is_still_stopped(
    fleet: FleetHarness, client: FleetClient
) -> None:
    """Before: ``fleet reset`` printed "reset sent" and exited 0 while nothing was released.
    The CLI runs as a process whose clock is 30 s ahead (its ``time.time_ns``)."""
    client.estop(None, reason="before a skewed reset", timeout_s=10.0)
    ahead = (
        "import time, sys; real = time.time_ns; time.time_ns = lambda: real() + 30 * 10**9; "
        "from fleet.cli.main import main; sys.exit(main(sys.argv[1:]))"
    )
    argv = ["reset", "--inventory", str(fleet.inventory_path), "--timeout", "5"]
    skewed = subprocess.run(
        [sys.executable, "-c", ahead, *argv], capture_output=True, text=True, timeout=60
    )
    assert skewed.returncode == 1, skewed.stdout + skewed.stderr
    for kind in KINDS:
        line = next(x for x in skewed.stdout.splitlines() if x.startswith(kind.label(client)))
        assert "STILL STOPPED: reset refused" in line and "ahead" in line, skewed.stdout
    assert "reset sent" not in skewed.stdout
    sane = subprocess.run(
        [sys.executable, "-m", "fleet.cli.main", *argv],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert sane.returncode == 0, sane.stdout + sane.stderr
    for kind in KINDS:
        line = next(x for x in sane.stdout.splitlines() if x.startswith(kind.label(client)))
        assert ": released" in line, sane.stdout


@pytest.mark.parametrize("kind", KINDS, ids=KIND_IDS)
def test_a_command_stamped_far_ahead_is_refused_and_the_owners_next_one_runs(
    fleet: FleetHarness, client: FleetClient, kind: Kind
) -> None:
    """Before: a command from a host 30 s ahead never expired, and as its owner's newest it
    made every later command of the owner "out of order" for 30 s. The owner's next command
    comes from another client (a host with a sane clock)."""
    _released(client, kind)
    owner = f"clock-{uuid.uuid4().hex[:8]}"
    ahead = with_envelope(kind.moves(), owner=owner, stamp_ns=_stamp(30 * NS), lifetime_s=1.0)
    refused = send(client, kind, ahead)
    assert not refused.ok and refused.code == ErrorCode.PARAMETER, refused
    assert "ahead of this agent's clock" in refused.message, refused
    sane = fleet.client()
    served = send(sane, kind, with_envelope(kind.moves(), owner=owner))
    assert served.ok, served
    send(sane, kind, release(kind, owner))


def test_the_viewers_reset_tells_what_it_did_to_each_unit(
    fleet: FleetHarness, client: FleetClient
) -> None:
    """Before: the viewer logged "reset sent" whatever the agents did."""
    from viewer.commands import Commander

    notes: list[tuple[str, str, bool]] = []
    inventory = fleet.inventory.with_principal("operator")
    with Commander(inventory, client.session, notify=lambda *n: notes.append(n)) as viewer:
        _released(client, KINDS[2])
        _stopped(client, KINDS[2])
        assert viewer.reset("h1")
        wait_until(lambda: len(notes) == 1, 10.0)
        assert notes[0] == ("reset h1", "released g1/h1", False), notes
        assert viewer.reset("h1")
        wait_until(lambda: len(notes) == 2, 10.0)
        assert notes[1] == ("reset h1", "nothing was stopped", False), notes
