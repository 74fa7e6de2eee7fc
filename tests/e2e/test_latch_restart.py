"""A stopped arm comes back stopped when its agent restarts (killed, crashed, host rebooted):
the latch is kept on disk at the edge and restored before any command is served; only a reset
releases it. Real processes: router, simulator, agent killed with SIGKILL and started again."""

from __future__ import annotations

import errno
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from edge_agent.latches import latch_dir
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode
from testkit.collect import Collector
from testkit.harness import FleetHarness, wait_until
from testkit.kinds import KIND_IDS, KINDS, Kind, LatchWatch, devices_fleet


def _status(client, arm: str) -> m.ArmStatus | None:  # type: ignore[no-untyped-def]
    return client.snapshot([arm], wait_s=1.0)[arm][0]


def test_a_stopped_arm_comes_back_stopped_after_an_agent_restart(
    fleet_harness: FleetHarness,
) -> None:
    h = fleet_harness
    client = h.start_fleet()
    acks = client.estop(arm="a1", reason="operator stop", timeout_s=5.0)
    stop = acks["a1"]
    assert stop is not None and stop.done
    h.stop("agent", sig=signal.SIGKILL)
    restored: list[m.StopAck] = []
    sub = client.session.declare_subscriber(
        client.keys.arm("a1", keys.ESTOP_ACK),
        lambda s: restored.append(payloads.STOP_ACK.decode(s.payload.to_bytes())),
    )
    try:
        h.start_agent(name="agent")
        wait_until(lambda: (s := _status(client, "a1")) is not None and s.link == "ok", 20.0)
        status = _status(client, "a1")
        assert status is not None and status.estopped, status
        assert "before the agent restarted" in (status.stop_reason or "")
        refused = client.command("a1", m.MoveJoint(joint=0, angle_deg=20.0))
        assert refused.error is not None and refused.error.code == ErrorCode.REJECTED
        # The restored stop is written to the arm again and acknowledged, same stop id.
        wait_until(lambda: any(a.stop_id == stop.stop_id for a in restored), 5.0)
    finally:
        sub.undeclare()
    client.reset("a1")
    wait_until(lambda: (s := _status(client, "a1")) is not None and not s.estopped, 5.0)
    # The reset is on disk once the latch file is gone (removed on the agent's latches thread,
    # just after the status says so): a kill before that brings the arm back stopped, which is
    # the safe side (seen in a fresh-clone run at load 8-14).
    latch_file = latch_dir(h.tmp_path / "state", h.inventory.fleet, h.domain) / "a1.stop.json"
    wait_until(lambda: not latch_file.exists(), 5.0)
    h.stop("agent", sig=signal.SIGKILL)
    h.start_agent(name="agent")  # after a reset, a restart brings the arm back free
    wait_until(lambda: (s := _status(client, "a1")) is not None and s.link == "ok", 20.0)
    assert client.command("a1", m.MoveJoint(joint=0, angle_deg=5.0, wait_reached=True)).ok


# ---------------------------------------------------------------- a full disk, a planted link


@pytest.fixture(scope="module")
def full_disk_fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FleetHarness]:
    """An agent serving every kind whose state directory is a 64 KiB tmpfs of its own (root
    only: the test mounts it), so the test can fill the disk under a running agent."""
    tmp_path = tmp_path_factory.mktemp("full-disk")
    state = tmp_path / "state"  # the harness's D1_FLEET_STATE_DIR
    state.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(state)],
        capture_output=True,
        text=True,
        check=False,
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs to fill (needs root): {mounted.stderr.strip()}")
    try:
        with devices_fleet(tmp_path) as harness:
            client = harness.client()
            for kind in KINDS:
                wait_until(LatchWatch(client, kind).link_ok, 30.0)
            yield harness
    finally:
        subprocess.run(["umount", "-l", str(state)], check=False)


def _fill(directory: Path) -> Path:
    """Fill the file system of ``directory`` to the last byte; the filler's path."""
    filler = directory / "filler"
    with open(filler, "wb", buffering=0) as out:  # unbuffered: nothing left to flush
        try:
            while True:
                out.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC, exc
    return filler


@pytest.mark.parametrize("kind", KINDS, ids=KIND_IDS)
def test_a_stop_the_disk_cannot_hold_is_said_in_status_and_counted(
    full_disk_fleet: FleetHarness, kind: Kind
) -> None:
    """On a full disk the latch file cannot be written: the unit still stops, its status
    says the stop is not persisted (a restart would forget it) and the diag counts it; once
    the disk has room, the agent's retry writes it and the status says nothing more."""
    harness = full_disk_fleet
    client = harness.client()
    watch = LatchWatch(client, kind)
    diags = Collector(client.session, client.unit_key(kind.unit, keys.DIAG), payloads.DIAG.decode)
    client.reset(kind.unit)
    wait_until(lambda: watch.estopped() is False and diags.latest() is not None, 10.0)
    before = diags.latest().latch_failures  # type: ignore[union-attr]
    filler = _fill(harness.tmp_path / "state")
    try:
        client.estop(kind.unit, reason="on a full disk", wait_still=False)
        wait_until(lambda: watch.estopped() and "NOT PERSISTED" in watch.reason(), 10.0)
        assert "No space left" in watch.reason(), watch.reason()
        wait_until(lambda: diags.latest().latch_failures > before, 5.0)  # type: ignore[union-attr]
    finally:
        filler.unlink()
    # Room again: the agent's retry writes the stop, and the status says nothing more.
    wait_until(lambda: "NOT PERSISTED" not in watch.reason(), 5.0)
    assert watch.estopped() and "on a full disk" in watch.reason(), watch.reason()
    state = latch_dir(harness.tmp_path / "state", harness.inventory.fleet, harness.domain)
    assert "on a full disk" in (state / f"{kind.unit}.stop.json").read_text()
    client.reset(kind.unit)
    diags.close()


def test_an_agent_refuses_a_symlinked_latch_directory(tmp_path: Path) -> None:
    """A symbolic link where the fleet's latch directory goes: the agent exits 2 at start-up
    saying so, and writes nothing through it."""
    with FleetHarness(tmp_path) as harness:
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
        (tmp_path / "state").mkdir()
        (tmp_path / "state" / harness.inventory.fleet).symlink_to(elsewhere)
        agent = harness.start_agent()
        assert agent.wait(timeout=20.0) == 2, harness.log("agent")
        assert "symbolic link" in harness.log("agent"), harness.log("agent")
        assert list(elsewhere.iterdir()) == []
