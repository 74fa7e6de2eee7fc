"""A DDS participant on an arm's own topics, run on the arm's host in the lab.

``spy``: print every string on a topic (default the command topic) as a JSON line
``{"t_ns": ..., "data": ...}``: what the arm received, to count executions.

``rogue``: a participant nobody invited, writing on the arm's feedback topic at ``--rate`` Hz
for ``--for-s`` seconds: malformed strings (not JSON, nested, wrong types, unknown
address/funcode, oversize) and forged angle reports that look valid (``--forge`` angles). The
D1 protocol has no authentication: a forged report cannot be told apart from the arm's own.

``forge``: the same on a device's own state topic, with Unitree's own IDL classes
(``unitree-dds-wrapper``, a far side nobody here wrote): at ``--rate`` Hz for ``--for-s``
seconds, a state that looks valid and is not the device's (``--device gripper``: a Dex1-1
``MotorStates_`` of family go at position ``--value`` rad; ``--device g1``: a G1
``SportModeState_`` in FSM ``--value``, dynamic). It prints its start and end (``t_ns``) and how
many it wrote.

``python -m tests.netlab.ddstool spy|rogue|forge --domain D --interface IF --peer IP [...]``
"""

from __future__ import annotations

import argparse
import itertools
import json
import signal
import sys
import threading
import time
from typing import Any

from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fleet.d1 import dds
from fleet.d1 import protocol as p

NEST = 1000
MALFORMED = [
    "not json at all",
    "",
    '{"seq":10,"address":2,"funcode":1,"data":' + "[" * NEST + "]" * NEST + "}",
    '{"seq":10,"address":2,"funcode":1,"data":{"angle0":"NaN"}}',
    '{"seq":10,"address":2,"funcode":1,"data":{"angle0":1e999}}',
    '{"seq":"x","address":2,"funcode":1}',
    '{"seq":10,"address":9,"funcode":9,"data":{}}',  # unknown address/funcode
    '{"seq":10,"address":2,"funcode":1,"data":{"x":"' + "z" * 8000 + '"}}',
    '{"seq":10,"address":2,"funcode":1,"data":{"angle0":' + "9" * 5000 + "}}",
]
"""Strings an arm never sends; each is dropped and counted by the agent."""


def _args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="ddstool")
    parser.add_argument("mode", choices=["spy", "rogue", "forge"])
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--interface", required=True)
    parser.add_argument("--peer", action="append", default=[])
    parser.add_argument("--suffix", default="")
    parser.add_argument("--topic", choices=["command", "feedback"], default=None)
    parser.add_argument("--rate", type=float, default=100.0, help="rogue: strings per second")
    parser.add_argument("--for-s", type=float, default=5.0, help="rogue: how long")
    parser.add_argument("--forge", type=float, nargs=7, default=None, help="rogue: angles")
    parser.add_argument("--device", choices=["gripper", "g1"], help="forge: the device's kind")
    parser.add_argument("--state-topic", help="forge: the device's state topic")
    parser.add_argument("--value", type=float, help="forge: gripper q (rad), G1 fsm_id")
    return parser.parse_args(argv)


def spy(channel: dds.DdsChannel, topic_name: str, stop: threading.Event) -> None:
    """Print every sample on ``topic_name`` until ``stop``."""
    topic = Topic(channel.participant, topic_name, dds.ArmString_)
    reader = DataReader(channel.participant, topic, qos=dds.COMMAND_READER_QOS)
    # Ready once the agent's writer matched: commands written before that are not seen.
    while reader.get_subscription_matched_status().current_count < 1 and not stop.is_set():
        stop.wait(0.02)
    print(json.dumps({"ready": True}), flush=True)
    while not stop.is_set():
        for sample in reader.take(N=256):
            data = getattr(sample, "data_", None)  # InvalidSample when a writer goes away
            if data is not None:
                print(json.dumps({"t_ns": time.time_ns(), "data": data}), flush=True)
        stop.wait(0.005)


def rogue(channel: dds.DdsChannel, topic_name: str, args: argparse.Namespace) -> None:
    """Write malformed and forged strings at ``args.rate`` for ``args.for_s`` seconds."""
    topic = Topic(channel.participant, topic_name, dds.ArmString_)
    writer = DataWriter(channel.participant, topic, qos=dds.FEEDBACK_WRITER_QOS)
    deadline = time.monotonic() + 10.0
    while writer.get_publication_matched_status().current_count < 1:
        if time.monotonic() > deadline:
            print(json.dumps({"error": "no reader matched"}), flush=True)
            return
        time.sleep(0.05)
    forged = None
    if args.forge is not None:
        forged = p.encode_message(p.JointAngles(angles_deg=tuple(args.forge)))
    print(json.dumps({"ready": True, "forged": forged}), flush=True)
    counts = {"malformed": 0, "forged": 0}
    period = 1.0 / args.rate
    start = time.monotonic()
    garbage = itertools.cycle(MALFORMED)
    for n in itertools.count():
        due = start + n * period
        if due - start > args.for_s:
            break
        time.sleep(max(0.0, due - time.monotonic()))
        writer.write(dds.ArmString_(next(garbage)))
        counts["malformed"] += 1
        if forged is not None:
            writer.write(dds.ArmString_(forged))
            counts["forged"] += 1
    print(json.dumps({"done": True, **counts}), flush=True)


def forged_state(device: str, value: float) -> tuple[type, Any]:
    """(Unitree's IDL class, one forged sample) of a ``device`` (``gripper``: a Dex1-1 of
    family go at position ``value`` rad; ``g1``: a G1 in FSM ``value``, dynamic: walking)."""
    # Imported here: the spy and the rogue (the D1's own tools) do without Unitree's package.
    if device == "gripper":
        from unitree_dds_wrapper.idl.unitree_go.msg import dds_ as go

        return go.MotorStates_, go.MotorStates_(states=[go.MotorState_(q=value, temperature=30)])
    from unitree_dds_wrapper.idl.unitree_hg.msg import dds_ as hg

    forged = hg.SportModeState_(fsm_id=int(value), fsm_mode=1, task_time=0.0)
    return hg.SportModeState_, forged


def forge(channel: dds.DdsChannel, args: argparse.Namespace, stop: threading.Event) -> None:
    """Write a forged state of ``args.device`` on its state topic at ``args.rate`` for
    ``args.for_s`` seconds (or until ``stop``)."""
    idl, sample = forged_state(args.device, args.value)
    writer = DataWriter(channel.participant, Topic(channel.participant, args.state_topic, idl))
    deadline = time.monotonic() + 10.0
    while writer.get_publication_matched_status().current_count < 1:
        if time.monotonic() > deadline or stop.is_set():
            print(json.dumps({"error": "no reader matched"}), flush=True)
            return
        time.sleep(0.05)
    print(json.dumps({"ready": True, "t_ns": time.time_ns()}), flush=True)
    period = 1.0 / args.rate
    start = time.monotonic()
    written = 0
    for n in itertools.count():
        due = start + n * period
        if due - start > args.for_s or stop.is_set():
            break
        time.sleep(max(0.0, due - time.monotonic()))  # pacing: the flood's rate
        writer.write(sample)
        written += 1
    print(json.dumps({"done": True, "t_ns": time.time_ns(), "forged": written}), flush=True)


def main(argv: list[str] | None = None) -> int:
    """Run one mode until done (rogue, forge) or SIGTERM (spy)."""
    args = _args(argv)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    channel = dds.DdsChannel(args.domain, args.interface, tuple(args.peer))
    try:
        if args.mode == "spy":
            spy(channel, dds.command_topic(args.suffix), stop)
        elif args.mode == "rogue":
            rogue(channel, dds.feedback_topic(args.suffix), args)
        else:
            forge(channel, args, stop)
    finally:
        channel.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
