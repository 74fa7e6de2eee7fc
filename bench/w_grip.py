"""Worker: one Dex1-1's state stream (``MotorStates_``, Unitree's ``go`` family) at
``--rate-hz`` on DDS, and a plain Zenoh subscriber on its ``gripper/<id>/state``.

Every sample's position carries its number (``marker_q``), so a relayed state (the newest
sample at the relay rate) is matched to the send time of the DDS sample it carries: the latency
DDS -> agent -> Zenoh at the configured rate. Writer and subscriber share one clock.
"""

from __future__ import annotations

import threading
import time

import zenoh
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from bench import workerlib
from fleet.d1 import dds
from fleet.dex1 import dds as ddx
from fleet.dex1 import idl
from fleet.dex1.kind import KIND
from fleet.wire import keys
from fleet.wire.session import open_client

MARK_BASE_RAD = 0.5
MARK_STEP_RAD = 0.0005
MARK_MOD = 8000
"""Positions 0.5 .. 4.5 rad; the relay rounds to 1e-5 rad, well under a step."""


def marker_q(k: int) -> float:
    """The position carrying sample number ``k`` (modulo ``MARK_MOD``)."""
    return MARK_BASE_RAD + (k % MARK_MOD) * MARK_STEP_RAD


def marker_of(q_rad: float) -> int:
    """Sample number modulo ``MARK_MOD`` of a position from ``marker_q``."""
    return round((q_rad - MARK_BASE_RAD) / MARK_STEP_RAD) % MARK_MOD


def run(args_inventory: str, device: str, rate_hz: float, max_s: float) -> dict:
    """Write until stdin closes; returns send times and (marker, receive time, dds_samples)."""
    inventory = workerlib.load_inventory(args_inventory)
    config = inventory.device(device)
    channel = dds.DdsChannel(*inventory.device_network([device]))
    topic = Topic(channel.participant, config.state_topic, idl.MotorStates_)
    writer = DataWriter(channel.participant, topic, qos=ddx.STATE_WRITER_QOS)
    space = keys.KeySpace(inventory.fleet)
    lock = threading.Lock()
    received: list[tuple[bytes, int]] = []

    def on_sample(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        with lock:
            if len(received) < 100_000:  # bounded: 50 Hz for half an hour
                received.append((sample.payload.to_bytes(), now))

    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and not writer.get_matched_subscriptions():
        time.sleep(0.05)
    matched = bool(writer.get_matched_subscriptions())
    sent: list[int] = []
    with open_client(inventory.endpoints) as session:
        sub = session.declare_subscriber(space.device("gripper", device, keys.STATE), on_sample)
        done = workerlib.ready()
        period_s = 1.0 / rate_hz
        next_s = time.monotonic()
        end = time.monotonic() + max_s
        motor = idl.GoMotorState_(mode=1, tau_est=0.1, temperature=30)
        while not done.is_set() and time.monotonic() < end:
            motor.q = marker_q(len(sent))
            sent.append(time.time_ns())
            writer.write(idl.MotorStates_(states=[motor]))
            next_s += period_s
            delay = next_s - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        sub.undeclare()
    channel.close()
    decode = KIND.payloads[keys.STATE].decode
    got = []
    with lock:
        for payload, now in received:
            state = decode(payload)
            got.append([marker_of(state.q_rad), now, state.dds_samples])
    return {"matched": matched, "sent_ns": sent, "received": got}


def main() -> None:
    """``python -m bench.w_grip --inventory inv.toml --device g1 --rate-hz 500``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("--device", required=True)
    parser.add_argument("--rate-hz", type=float, default=500.0)
    args = parser.parse_args()
    workerlib.emit(run(args.inventory, args.device, args.rate_hz, args.max_s))


if __name__ == "__main__":
    main()
