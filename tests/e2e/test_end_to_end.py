"""One arm end to end: simulated arm + agent + router + a plain client, all real processes.

The test process also joins as a plain Zenoh client and, where a test needs to see or forge the
arm's own traffic, as a DDS participant on the harness's domain (never mocked).
"""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TypeVar

import msgspec
import pytest
import zenoh
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fleet.d1 import dds
from fleet.d1 import protocol as p
from fleet.sim.faults import FaultReply
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode
from testkit.collect import Collector
from testkit.harness import FleetHarness, wait_until

T = TypeVar("T")


def _key(harness: FleetHarness, channel: str, arm: str = "a1") -> str:
    return keys.KeySpace(harness.inventory.fleet).arm(arm, channel)


@contextmanager
def _dds_channel(harness: FleetHarness) -> Iterator[dds.DdsChannel]:
    """The test's own DDS participant on the harness's domain, on loopback."""
    channel = dds.DdsChannel(harness.domain, "lo")
    try:
        yield channel
    finally:
        channel.close()


def _texts(reader: DataReader) -> list[str]:
    return [s.data_ for s in reader.take(N=64) if getattr(s, "data_", None) is not None]


# ----------------------------------------------------------------------------- tests


def test_move_joints_is_acknowledged_and_reached(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    target = [10.0, -30.0, 40.0, 0.0, 20.0, 5.0, 10.0]
    reply = client.command("a1", m.MoveJoints(angles_deg=target, mode=1, wait_reached=True))
    assert reply.ok, reply.error
    assert reply.received and reply.reached
    assert reply.seq is not None and reply.seq != 10
    _status, joints = client.snapshot(["a1"])["a1"]
    assert joints is not None
    assert all(abs(a - t) <= 2.0 for a, t in zip(joints.angles_deg, target, strict=True))


@pytest.mark.timing
def test_joints_arrive_at_about_10_hz(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    joints = Collector(client.session, _key(fleet_harness, keys.JOINTS), payloads.JOINTS.decode)
    wait_until(lambda: len(joints) >= 1, 5.0)
    time.sleep(2.0)  # the measurement window
    timed = joints.timed
    samples = [j for _t, j in timed]
    span_s = (samples[-1].stamp_ns - samples[0].stamp_ns) / 1e9
    rate_hz = (len(samples) - 1) / span_s
    assert 8.0 <= rate_hz <= 11.5, (rate_hz, len(samples), span_s)
    received_rate_hz = (len(timed) - 1) / (timed[-1][0] - timed[0][0])
    assert 8.0 <= received_rate_hz <= 11.5, received_rate_hz
    seqs = [j.seq for j in samples]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a joints sample went missing"
    assert all(len(j.angles_deg) == 7 for j in samples)


def test_out_of_range_is_refused_without_reaching_dds(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    raw = Collector(client.session, _key(fleet_harness, keys.RAW_COMMAND), bytes.decode)
    joints = Collector(client.session, _key(fleet_harness, keys.JOINTS), payloads.JOINTS.decode)
    with _dds_channel(fleet_harness) as channel:
        topic = Topic(channel.participant, dds.command_topic("_1"), dds.ArmString_)
        reader = DataReader(channel.participant, topic, qos=dds.COMMAND_READER_QOS)
        wait_until(lambda: reader.get_subscription_matched_status().current_count >= 1, 10.0)
        seen: list[str] = []

        def sees(angle: float) -> bool:
            seen.extend(_texts(reader))
            return any(p.decode_command(t)[1] == p.SetJointAngle(0, angle) for t in seen)

        def seen_after_sending() -> bool:
            # The reader can match the agent's writer before the writer matches the reader
            # (volatile: what is sent before then never reaches us), so send until one arrives.
            if sees(1.0):
                return True
            before = client.command("a1", m.MoveJoint(joint=0, angle_deg=1.0))
            assert before.ok, before.error
            return False

        # A valid command first: proves this reader sees what the agent writes.
        wait_until(seen_after_sending, 10.0, interval_s=0.2)
        seen.clear()
        raw_before = len(raw)
        for bad in (
            m.MoveJoint(joint=1, angle_deg=120.0),
            m.MoveJoint(joint=7, angle_deg=0.0),  # the arm would ack it and stop its feed
            m.MoveJoint(joint=6, angle_deg=70.0),
            m.MoveJoints(angles_deg=[0.0, 0.0, 95.0, 0.0, 0.0, 0.0, 0.0]),
            m.MoveJoints(angles_deg=[0.0] * 6),
        ):
            reply = client.command("a1", bad)
            assert not reply.ok and reply.error is not None, bad
            assert reply.error.code == ErrorCode.PARAMETER == 3204, reply.error
            assert reply.seq is None
        # A valid command after: everything written in between has arrived before it.
        after = client.command("a1", m.MoveJoint(joint=0, angle_deg=2.0))
        assert after.ok, after.error
        wait_until(lambda: sees(2.0), 5.0)
        assert [p.decode_command(t)[1] for t in seen] == [p.SetJointAngle(0, 2.0)]
        wait_until(lambda: len(raw) >= raw_before + 1, 5.0)
        assert [p.decode_command(t)[1] for t in raw.items[raw_before:]] == [p.SetJointAngle(0, 2.0)]
    # The arm's angle feed is still running.
    count = len(joints)
    wait_until(lambda: len(joints) >= count + 5, 3.0)


def test_malformed_feedback_is_counted_and_joints_keep_arriving(
    fleet_harness: FleetHarness,
) -> None:
    client = fleet_harness.start_fleet()
    diag = Collector(client.session, _key(fleet_harness, keys.DIAG), payloads.DIAG.decode)
    joints = Collector(client.session, _key(fleet_harness, keys.JOINTS), payloads.JOINTS.decode)
    first = wait_until(diag.latest, 5.0)
    assert first.malformed == 0 and first.unknown_messages == 0
    with _dds_channel(fleet_harness) as channel:
        topic = Topic(channel.participant, dds.feedback_topic("_1"), dds.ArmString_)
        writer = DataWriter(channel.participant, topic, qos=dds.FEEDBACK_WRITER_QOS)
        wait_until(lambda: writer.get_publication_matched_status().current_count >= 1, 10.0)
        written = 0

        def counted() -> bool:
            nonlocal written
            latest = diag.latest()
            if latest is not None and latest.malformed >= 1 and latest.unknown_messages >= 1:
                return True
            # Best effort on both sides: a sample can be lost, so keep forging until counted.
            writer.write(dds.ArmString_('{"seq":10,"address":2,"funcode":1,"data":{"angle0":'))
            writer.write(dds.ArmString_('{"seq":10,"address":2,"funcode":1,"data":{"x":NaN}}'))
            writer.write(dds.ArmString_('{"seq":10,"address":7,"funcode":7,"data":{}}'))
            written += 1
            return False

        wait_until(counted, 10.0, interval_s=0.1)
    latest = diag.latest()
    assert latest is not None
    assert 1 <= latest.malformed <= 2 * written
    assert 1 <= latest.unknown_messages <= written
    assert latest.last_error
    count = len(joints)
    wait_until(lambda: len(joints) >= count + 5, 3.0)
    status, _joints = client.snapshot(["a1"])["a1"]
    assert status is not None and status.link == "ok"


def test_killed_arm_turns_the_link_stale_then_lost(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    status = Collector(client.session, _key(fleet_harness, keys.STATUS), payloads.STATUS.decode)
    wait_until(lambda: (s := status.latest()) is not None and s.link == "ok", 5.0)
    killed_at = time.monotonic()
    fleet_harness.stop("sim", sig=signal.SIGKILL)

    def first(link: str) -> float | None:
        return next((t for t, s in status.timed if s.link == link and t > killed_at), None)

    stale_at = wait_until(lambda: first("stale"), 3.0)
    lost_at = wait_until(lambda: first("lost"), 5.0)
    config = fleet_harness.inventory.arm("a1")
    assert stale_at - killed_at < config.link_stale_s + 1.0
    assert config.link_lost_s - config.link_stale_s - 0.3 < lost_at - stale_at
    assert lost_at - killed_at < config.link_lost_s + 1.0
    assert status.latest() is not None and status.latest().link == "lost"  # type: ignore[union-attr]
    reply = client.command("a1", m.MoveJoint(joint=0, angle_deg=5.0))
    assert reply.error is not None and reply.error.code == ErrorCode.REJECTED


def test_agent_token_disappears_when_the_agent_stops(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    assert client.agents_alive() == {"a1"}
    assert fleet_harness.stop("agent") == 0
    wait_until(lambda: client.agents_alive() == set(), 5.0)
    reply = client.command("a1", m.Zero())
    assert not reply.ok and reply.error is not None
    assert reply.error.code == ErrorCode.NO_AGENT


def _fault(client_session: zenoh.Session, key: str, payload: bytes) -> FaultReply:
    started = time.monotonic()
    errors = []
    for reply in client_session.get(key, payload=payload, timeout=5.0):
        if reply.ok is not None:
            return msgspec.json.decode(reply.ok.payload.to_bytes(), type=FaultReply)
        errors.append(reply.err.payload.to_bytes() if reply.err is not None else None)
    waited = time.monotonic() - started
    raise AssertionError(f"no reply from the simulator on {key} in {waited:.1f} s: {errors}")


def test_muted_acks_make_commands_time_out(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    fault_key = _key(fleet_harness, keys.SIM_FAULT)
    assert _fault(client.session, fault_key, b'{"op":"mute_acks","on":true}') == FaultReply(True)
    reply = client.command("a1", m.MoveJoint(joint=0, angle_deg=10.0))
    assert not reply.ok and reply.error is not None
    assert reply.error.code == ErrorCode.TIMEOUT == 3104, reply.error
    assert "no receive ack" in reply.error.message
    assert reply.received is False and reply.seq is not None
    # A bad fault request is answered with an error, not dropped.
    bad = _fault(client.session, fault_key, b'{"op":"explode"}')
    assert not bad.ok and bad.error
    # ... and the arm answers again once the fault is cleared.
    assert _fault(client.session, fault_key, b'{"op":"clear"}').ok
    reply = client.command("a1", m.MoveJoint(joint=0, angle_deg=0.0))
    assert reply.ok, reply.error


@pytest.mark.timing
def test_sigterm_stops_every_process_with_code_0(fleet_harness: FleetHarness) -> None:
    fleet_harness.start_fleet()
    for name in ("agent", "sim", "router"):
        started = time.monotonic()
        code = fleet_harness.stop(name, signal.SIGTERM, timeout_s=5.0)
        elapsed = time.monotonic() - started
        assert code == 0, (name, code, fleet_harness.log(name))
        assert elapsed < 5.0, (name, elapsed)


def test_a_streamed_target_past_its_lifetime_is_never_executed(fleet_harness: FleetHarness) -> None:
    import time

    client = fleet_harness.start_fleet()
    late = m.MoveJoint(
        joint=0, angle_deg=30.0, stamp_ns=time.time_ns() - 500_000_000, lifetime_s=0.2
    )
    reply = client.command("a1", late)
    assert not reply.ok and reply.error is not None
    assert reply.error.code == m.ErrorCode.EXPIRED and "lifetime" in reply.error.message
    fresh = m.MoveJoint(joint=0, angle_deg=30.0, stamp_ns=time.time_ns(), lifetime_s=0.2)
    assert client.command("a1", fresh).ok


def test_an_agent_stopped_mid_move_holds_its_arm(fleet_harness: FleetHarness) -> None:
    client = fleet_harness.start_fleet()
    target = [0.0, -80.0, 80.0, 0.0, 60.0, 0.0, 0.0]
    assert client.command("a1", m.MoveJoints(angles_deg=target, mode=1)).ok
    wait_until(lambda: (j := client.snapshot(["a1"])["a1"][1]) and j.angles_deg[1] < -20.0, 5.0)
    fleet_harness.stop("agent")  # SIGTERM while the arm is still on its way
    observer = fleet_harness.start_agent(name="observer")
    assert observer.poll() is None
    first = wait_until(lambda: client.snapshot(["a1"])["a1"][1], 15.0)
    assert abs(first.angles_deg[1] - target[1]) > 10.0, "the arm kept going to its old target"


def test_absurd_numbers_in_a_command_are_refused_and_the_agent_keeps_serving(
    fleet_harness: FleetHarness,
) -> None:
    client = fleet_harness.start_fleet()
    huge = b'{"op":"hold","stamp_ns":-' + b"9" * 400 + b',"lifetime_s":1}'
    replies = list(client.session.get(client.command_key("a1"), payload=huge, timeout=5.0))
    reply = payloads.REPLY.decode(replies[0].ok.payload.to_bytes())
    assert not reply.ok and reply.error is not None and reply.error.code == m.ErrorCode.PARAMETER
    assert "stamp_ns" in reply.error.message
    assert client.command("a1", m.Hold()).ok  # the command thread is still alive
