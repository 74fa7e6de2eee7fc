"""Synthetic fleet traffic for the viewer's benchmark: fake joints, status and agent tokens.

``python -m bench.synthetic --inventory inv.toml --rate-hz 10`` publishes, for every inventory
arm, a smooth made-up motion on ``arm/<arm>/joints`` at ``rate_hz``, a status every second, and
the agent's liveliness token, exactly as an agent would. No DDS, no simulated arm: only the key
space, so the viewer can be measured with hundreds of arms on one machine.
"""

from __future__ import annotations

import argparse
import math
import time

import zenoh

from fleet.inventory import Inventory
from fleet.runtime import add_inventory_options, inventory_from_args, shutdown_event
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.session import open_client

JSON = zenoh.Encoding.APPLICATION_JSON


def fake_angles(i: int, t: float) -> list[float]:
    """Arm ``i``'s made-up angles at time ``t`` (degrees, within the limits)."""
    phase = 0.37 * i
    return [
        60.0 * math.sin(0.5 * t + phase),
        30.0 * math.sin(0.7 * t + phase),
        -40.0 + 30.0 * math.sin(0.9 * t + phase),
        45.0 * math.sin(0.4 * t + phase),
        30.0 * math.sin(1.1 * t + phase),
        90.0 * math.sin(0.3 * t + phase),
        32.5 + 32.5 * math.sin(1.3 * t + phase),
    ]


def publish(inventory: Inventory, rate_hz: float, stop: object) -> int:
    """Publish until ``stop`` (a threading.Event) is set; returns the joints samples sent."""
    space = keys.KeySpace(inventory.fleet)
    arms = list(inventory.arms)
    sent = 0
    with open_client(inventory.endpoints) as session:
        drop = zenoh.CongestionControl.DROP
        joints = [
            session.declare_publisher(
                space.arm(a, keys.JOINTS), encoding=JSON, congestion_control=drop
            )
            for a in arms
        ]
        status = [session.declare_publisher(space.arm(a, keys.STATUS), encoding=JSON) for a in arms]
        tokens = [session.liveliness().declare_token(space.arm(a, keys.AGENT)) for a in arms]
        start = time.monotonic()
        next_tick, next_status = start, start
        while not stop.wait(max(0.0, next_tick - time.monotonic())):  # type: ignore[attr-defined]
            now = time.monotonic()
            next_tick += 1.0 / rate_hz
            stamp = time.time_ns()
            for i, pub in enumerate(joints):
                pub.put(m.encode(m.Joints(stamp, fake_angles(i, now - start), sent)))
                sent += 1
            if now >= next_status:
                next_status = now + 1.0
                for pub in status:
                    pub.put(
                        m.encode(
                            m.ArmStatus(
                                stamp,
                                "ok",
                                enabled=True,
                                powered=True,
                                error=False,
                                feedback_age_s=0.0,
                            )
                        )
                    )
        for token in tokens:
            token.undeclare()
    return sent


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__)
    add_inventory_options(parser)
    parser.add_argument("--rate-hz", type=float, default=10.0)
    args = parser.parse_args(argv)
    inventory = inventory_from_args(args)
    stop = shutdown_event()
    publish(inventory, args.rate_hz, stop)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
