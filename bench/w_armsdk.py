"""Worker: a lightweight rt/arm_sdk receiver beside a G1 (issue 23's jitter goal).

One DDS reader of ``rt/arm_sdk`` (the agent's 50 Hz ``LowCmd_`` stream) on a thread of its
own that only takes samples and stamps their arrival (monotonic ns, the weight); the main
thread keeps the stream engaged with an ``arm_target`` through the fleet's client every second
(the lease is 3 s), swinging the left shoulder pitch by 0.2 rad. No decoding, no CRC check, no
logging on the receive path: what is measured is the agent's sending rhythm plus DDS on
loopback, not the receiver.
"""

from __future__ import annotations

import threading
import time

from cyclonedds.core import (
    InstanceState,
    Policy,
    Qos,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from bench import workerlib
from fleet.client import FleetClient
from fleet.d1 import dds
from fleet.g1 import arms, idl
from fleet.g1.messages import ArmTarget

READER_QOS = Qos(
    Policy.Reliability.BestEffort, Policy.History.KeepLast(64), Policy.Durability.Volatile
)
"""Best effort (the robot's own reader is unknown; the agent's writer is reliable, which
matches), 64 deep so a late take loses nothing: the arrival stamps come from the take."""


def run(inventory_path: str, device: str, max_s: float) -> dict:
    """Receive until stdin closes; returns each message's arrival (ns) and weight."""
    inventory = workerlib.load_inventory(inventory_path)
    channel = dds.DdsChannel(*inventory.device_network([device]))
    topic = Topic(channel.participant, arms.CMD_TOPIC, idl.LowCmd_)
    reader = DataReader(channel.participant, topic, qos=READER_QOS)
    waitset = WaitSet(channel.participant)
    waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    arrivals: list[tuple[int, float]] = []
    done = threading.Event()

    def receive() -> None:
        while not done.is_set() and len(arrivals) < 200_000:
            waitset.wait(duration(milliseconds=100))
            now = time.monotonic_ns()
            for sample in reader.take(64):
                if hasattr(sample, "motor_cmd"):  # not an InvalidSample (a writer gone)
                    arrivals.append((now, float(sample.motor_cmd[arms.WEIGHT_INDEX].q)))

    receiver = threading.Thread(target=receive, name="armsdk-recv", daemon=True)
    receiver.start()
    refused = []
    with FleetClient(inventory) as client:
        stop = workerlib.ready()
        end = time.monotonic() + max_s
        k = 0
        while not stop.is_set() and time.monotonic() < end:
            q = [0.0] * arms.COUNT
            q[arms.LEFT_ARM[0]] = -0.2 * (k % 2)
            reply = client.device_command(device, ArmTarget(q_rad=q, speed_rad_s=0.5))
            if not reply.ok:
                refused.append(str(reply.error))
            k += 1
            stop.wait(1.0)
    done.set()
    receiver.join(timeout=2.0)
    channel.close()
    return {"arrivals": arrivals, "refused": refused[:5]}


def main() -> None:
    """``python -m bench.w_armsdk --inventory inv.toml --device h1``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("--device", required=True)
    args = parser.parse_args()
    workerlib.emit(run(args.inventory, args.device, args.max_s))


if __name__ == "__main__":
    main()
