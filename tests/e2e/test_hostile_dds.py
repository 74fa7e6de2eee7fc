"""Hostile strings on the arm's own DDS topics (any participant on the domain can write them)
and a hostile fault request to the simulator: none may blind the agent or stop the simulator.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from fleet.client import FleetClient
from fleet.d1 import dds
from fleet.wire import keys
from fleet.wire import messages as m
from testkit.harness import FleetHarness, wait_until
from testkit.hostile import NEST, assert_fleet_stops_and_serves, decode, latest, nested

NESTED_FEEDBACK = '{"seq":10,"address":2,"funcode":1,"data":' + "[" * NEST + "]" * NEST + "}"
HUGE_FEEDBACK = '{"seq":10,"address":2,"funcode":1,"data":{"x":"' + "z" * 100_000 + '"}}'


@contextmanager
def _writer(harness: FleetHarness, topic_name: str) -> Iterator[DataWriter]:
    channel = dds.DdsChannel(harness.domain, "lo")
    try:
        topic = Topic(channel.participant, topic_name, dds.ArmString_)
        writer = DataWriter(channel.participant, topic, qos=dds.COMMAND_WRITER_QOS)
        wait_until(lambda: writer.get_publication_matched_status().current_count >= 1, 10.0)
        yield writer
    finally:
        channel.close()


def _joints_seq(client: FleetClient) -> int:
    _status, joints = client.snapshot(["a1"], wait_s=1.0)["a1"]
    assert joints is not None
    return joints.seq


def test_a_poison_feedback_string_never_blinds_the_agent(fleet_harness: FleetHarness) -> None:
    h = fleet_harness
    client = h.start_fleet()
    h.start_coordinator()
    with _writer(h, dds.feedback_topic("_1")) as writer:
        for _ in range(5):  # best effort: a sample can be lost, so send a few
            writer.write(dds.ArmString_(NESTED_FEEDBACK))
            writer.write(dds.ArmString_(HUGE_FEEDBACK))
            time.sleep(0.05)
    before = _joints_seq(client)
    # Joints keep flowing: five more samples (0.5 s at 10 Hz; none if the thread died).
    wait_until(lambda: _joints_seq(client) >= before + 5, 10.0)
    status, _joints = client.snapshot(["a1"])["a1"]
    assert status is not None and status.link == "ok"
    diag = decode(m.Diag, latest(client, client.keys.arm("a1", keys.DIAG), wait_s=2.5))
    assert diag.malformed >= 1, diag  # type: ignore[attr-defined]
    assert_fleet_stops_and_serves(h, client)


def test_a_poison_command_string_never_stops_the_simulated_arm(
    fleet_harness: FleetHarness,
) -> None:
    h = fleet_harness
    client = h.start_fleet()
    with _writer(h, dds.command_topic("_1")) as writer:
        for _ in range(5):
            writer.write(dds.ArmString_(NESTED_FEEDBACK.replace('"address":2', '"address":1')))
            writer.write(dds.ArmString_(HUGE_FEEDBACK))
            time.sleep(0.05)
    before = _joints_seq(client)
    # Joints keep flowing: five more samples (0.5 s at 10 Hz; none if the thread died).
    wait_until(lambda: _joints_seq(client) >= before + 5, 10.0)
    assert h.processes["sim"].poll() is None


def test_a_poison_fault_request_is_refused_and_the_simulator_goes_on(
    fleet_harness: FleetHarness,
) -> None:
    h = fleet_harness
    client = h.start_fleet()
    key = client.keys.arm("a1", keys.SIM_FAULT)
    for payload in (nested(b'"op":"stall","joint":1,"angle_deg":5'), b"\xff\xfe", b"[" * 100_000):
        replies = [r.ok.payload.to_bytes() for r in client.session.get(key, payload=payload)]
        assert replies and b'"ok":false' in replies[0], replies
    before = _joints_seq(client)
    # Joints keep flowing: five more samples (0.5 s at 10 Hz; none if the thread died).
    wait_until(lambda: _joints_seq(client) >= before + 5, 10.0)
    assert h.processes["sim"].poll() is None
