"""The agent's WaitSet names the readers with data and wakes on close, on a real DDS
participant (the hot path's pure pieces are in tests/unit/test_relay_path.py)."""

from __future__ import annotations

import time

from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from edge_agent.link import ReadySet
from fleet.d1 import dds
from testkit.harness import claim_domain


def test_the_waitset_names_exactly_the_readers_with_data_and_wakes_on_close() -> None:
    domain, lock = claim_domain()
    channel = dds.DdsChannel(domain)
    try:
        participant = channel.participant
        readers, writers = [], []
        for suffix in ("_1", "_2", "_3"):
            topic = Topic(participant, dds.feedback_topic(suffix), dds.ArmString_)
            readers.append(DataReader(participant, topic, qos=dds.FEEDBACK_READER_QOS))
            writers.append(DataWriter(participant, topic, qos=dds.FEEDBACK_WRITER_QOS))
        ready = ReadySet(participant, readers)
        assert ready.wait(0.05) == []
        writers[1].write(dds.ArmString_("x"))
        deadline = time.monotonic() + 5.0
        got: list[int] = []
        while not got and time.monotonic() < deadline:
            got = ready.wait(0.5)
        assert got == [1]
        assert ready.wait(0.01) == [1], "a reader stays ready until its samples are taken"
        assert [s.data_ for s in readers[1].take(N=8)] == ["x"]
        writers[0].write(dds.ArmString_("a"))
        writers[2].write(dds.ArmString_("c"))
        deadline = time.monotonic() + 5.0
        while sorted(got) != [0, 2] and time.monotonic() < deadline:
            got = ready.wait(0.5)
        assert sorted(got) == [0, 2]
        readers[0].take(N=8)
        readers[2].take(N=8)
        started = time.monotonic()
        ready.wake()
        assert ready.wait(5.0) == []
        assert time.monotonic() - started < 1.0, "wake() did not end the wait"
    finally:
        channel.close()
        lock.close()
