"""Worker: simulated-arm-like feedback writers, one per arm, each at ``--rate-hz``.

Every sample is a real joint report (2/1) through the D1 codec; angles 0 and 1 carry a marker
(the sample's number) so a subscriber on ``arm/<arm>/joints`` can match it to its send time,
since the codec accepts nothing but angles in a joint report. The arms' phases are spread
evenly, like independent arms, instead of all writing in the same instant.
"""

from __future__ import annotations

import time

from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from bench import workerlib
from fleet.d1 import dds
from fleet.d1.protocol import JointAngles, encode_message


def marker_angles(k: int) -> tuple[float, ...]:
    """Angles carrying sample number ``k`` (< 200000) within the joint limits."""
    return (float(k // 1000) - 100.0, (k % 1000) / 10.0 - 50.0, 10.0, 20.0, -10.0, 5.0, 30.0)


def marker_of(angles_deg: list[float]) -> int:
    """The sample number ``marker_angles`` put into ``angles_deg``."""
    return (round(angles_deg[0]) + 100) * 1000 + round((angles_deg[1] + 50.0) * 10.0)


def run(args_inventory: str, rate_hz: float, max_s: float) -> dict:
    """Write until stdin closes; returns every (arm index, sample number, send time)."""
    inventory = workerlib.load_inventory(args_inventory)
    arms = list(inventory.arms.values())
    channel = dds.DdsChannel(inventory.domain_of(arms[0]), "lo")
    writers = []
    for arm in arms:
        topic = Topic(channel.participant, dds.feedback_topic(arm.suffix), dds.ArmString_)
        writers.append(DataWriter(channel.participant, topic, qos=dds.FEEDBACK_WRITER_QOS))
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and not all(w.get_matched_subscriptions() for w in writers):
        time.sleep(0.05)
    matched = sum(1 for w in writers if w.get_matched_subscriptions())
    done = workerlib.ready()
    sent: list[list[int]] = [[] for _ in arms]  # per arm: send time of sample k at index k
    slot_s = 1.0 / (rate_hz * len(arms))
    next_s = time.monotonic()
    end = time.monotonic() + max_s
    slot = 0
    while not done.is_set() and time.monotonic() < end:
        i = slot % len(arms)
        k = len(sent[i])
        text = encode_message(JointAngles(marker_angles(k)))
        sent[i].append(time.time_ns())
        writers[i].write(dds.ArmString_(text))
        slot += 1
        next_s += slot_s
        delay = next_s - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    channel.close()
    return {"arms": len(arms), "matched": matched, "sent_ns": sent}


def main() -> None:
    """``python -m bench.w_feed --inventory inv.toml --rate-hz 10``."""
    parser = workerlib.parser(__doc__)
    parser.add_argument("--rate-hz", type=float, default=10.0)
    args = parser.parse_args()
    workerlib.emit(run(args.inventory, args.rate_hz, args.max_s))


if __name__ == "__main__":
    main()
