"""Worker: the raw DDS hop. ``writer`` writes feedback-sized ArmString_ samples stamped with
``time.time_ns()``; ``reader`` (another process) takes them the way the agent's link does (a
WaitSet, then ``take``) and records the one-way delay. Same topic type and QoS as the arm's
feedback, same loopback CycloneDDS configuration as the fleet."""

from __future__ import annotations

import time

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from bench import workerlib
from fleet.d1 import dds
from fleet.d1.protocol import JointAngles, encode_message

TOPIC = dds.feedback_topic("_rawbench")
FEEDBACK_SIZE = len(
    encode_message(JointAngles((-12.345, 67.891, -23.456, 45.678, 0.5, 90.0, 30.0)))
)
"""A joint report's length: the raw hop carries a string of the same size."""


def stamped(index: int) -> str:
    """``"<index> <time_ns> "`` padded to a joint report's length."""
    return f"{index} {time.time_ns()} ".ljust(FEEDBACK_SIZE, "x")


def run_writer(domain: int, count: int, warmup: int, rate_hz: float, max_s: float) -> dict:
    """Wait for the reader to match, then write ``warmup + count`` samples at ``rate_hz``."""
    channel = dds.DdsChannel(domain, "lo")
    topic = Topic(channel.participant, TOPIC, dds.ArmString_)
    writer = DataWriter(channel.participant, topic, qos=dds.FEEDBACK_WRITER_QOS)
    deadline = time.monotonic() + min(max_s, 20.0)
    while not writer.get_matched_subscriptions() and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.3)  # let the reader's side of discovery settle as well
    period = 1.0 / rate_hz
    next_s = time.monotonic()
    end = time.monotonic() + max_s
    sent = 0
    for index in range(warmup + count):
        if time.monotonic() > end:
            break
        writer.write(dds.ArmString_(stamped(index)))
        sent += 1
        next_s += period
        time.sleep(max(0.0, next_s - time.monotonic()))
    time.sleep(0.2)
    channel.close()
    return {"sent": sent}


def run_reader(domain: int, warmup: int, max_s: float) -> dict:
    """Take samples until stdin closes; one-way delays of every sample past the warm-up."""
    channel = dds.DdsChannel(domain, "lo")
    topic = Topic(channel.participant, TOPIC, dds.ArmString_)
    reader = DataReader(channel.participant, topic, qos=dds.FEEDBACK_READER_QOS)
    waitset = WaitSet(channel.participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    done = workerlib.ready()
    delays: list[int] = []
    received = 0
    end = time.monotonic() + max_s
    while not done.is_set() and time.monotonic() < end:
        waitset.wait(duration(milliseconds=100))
        samples = reader.take(N=64)
        now = time.time_ns()
        for sample in samples:
            text = getattr(sample, "data_", None)
            if text is None:
                continue
            index, sent_ns, _ = text.split(" ", 2)
            received += 1
            if int(index) >= warmup:
                delays.append(now - int(sent_ns))
    channel.close()
    return {"received": received, "delays_ns": delays}


def main() -> None:
    """``python -m bench.w_dds writer|reader --domain D ...``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("role", choices=["writer", "reader"])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    args = parser.parse_args()
    if args.role == "writer":
        workerlib.emit(run_writer(args.domain, args.count, args.warmup, args.rate_hz, args.max_s))
    else:
        workerlib.emit(run_reader(args.domain, args.warmup, args.max_s))


if __name__ == "__main__":
    main()
