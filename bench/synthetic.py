"""Synthetic fleet traffic for the viewer's benchmark: fake joints, status and agent tokens.

``python -m bench.synthetic --inventory inv.toml --rate-hz 10`` publishes, for every inventory
arm, a smooth made-up motion on ``arm/<arm>/joints`` at ``rate_hz``, a status every second, and
the agent's liveliness token, exactly as an agent would. No DDS, no simulated arm: only the key
space, so the viewer can be measured with hundreds of arms on one machine.

``--g1 ID`` (repeatable; a ``[g1.<id>]`` of the inventory) adds a G1 as its agent relays one: a
``g1/<id>/lowstate`` whose arms swing (legs and waist still) and a ``g1/<id>/state``, both at the
G1's ``relay_hz``, and its agent token. Built from the product's Structs and encoder.
"""

from __future__ import annotations

import argparse
import math
import time

import msgspec
import zenoh

from fleet.g1 import arms as g1_arms
from fleet.g1.config import G1Config
from fleet.g1.messages import G1LowState, G1State
from fleet.inventory import Inventory, InventoryError
from fleet.runtime import add_inventory_options, inventory_from_args, shutdown_event
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.session import open_client
from testkit.samples import g1_state

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


G1_LEGS_WAIST = g1_arms.FIRST + 3
"""The G1's motors 0-14 (legs, waist) stand still; 15-28 (both arms) swing."""


def fake_g1_q(t: float) -> list[float]:
    """A G1's 29 made-up joint angles at time ``t`` (rad, motor order): standing, both arms
    swinging over a third of their range around its middle, about 0.04 rad per 0.1 s."""
    q = [0.0] * g1_arms.MOTORS
    for k, (_name, lower, upper) in enumerate(g1_arms.JOINTS):
        motor = g1_arms.FIRST + k
        if motor >= G1_LEGS_WAIST:
            mid, half = (lower + upper) / 2.0, (upper - lower) / 2.0
            q[motor] = round(mid + 0.33 * half * math.sin(0.8 * t + 0.5 * k), 4)
    return q


def fake_g1_lowstate(t: float, tick: int, stamp_ns: int) -> G1LowState:
    """The lowstate a G1's agent relays (rounded as the agent does), level IMU."""
    return G1LowState(
        stamp_ns=stamp_ns,
        q_rad=fake_g1_q(t),
        imu_rpy=[0.0, 0.0, 0.0],
        imu_quaternion=[1.0, 0.0, 0.0, 0.0],
        tick=tick,
        bad_samples=0,
    )


def fake_g1_state(config: G1Config, stamp_ns: int, samples: int) -> G1State:
    """The state a G1's agent relays for a robot standing in the walking controller
    (testkit's sample: fsm 500, static, link ok, no stop) with this G1's settings."""
    service = None if config.service == "auto" else config.service
    return msgspec.structs.replace(
        g1_state(service, config.service, service is not None),
        stamp_ns=stamp_ns,
        stop_action=config.stop_action,
        dds_samples=samples,
        dds_rate_hz=config.sim_rate_hz,
    )


def g1_configs(inventory: Inventory, g1_ids: list[str]) -> list[G1Config]:
    """The inventory's ``[g1.<id>]`` of each of ``g1_ids`` (InventoryError if not a G1)."""
    configs = []
    for g1_id in g1_ids:
        device = inventory.device(g1_id)
        if not isinstance(device, G1Config):
            raise InventoryError(f"{inventory.path}: {g1_id!r} is not a [g1.<id>] device")
        configs.append(device)
    return configs


class _G1Feed:
    """One G1's publishers, token and relay cadence (``relay_hz``, as its agent's tick)."""

    def __init__(self, session: zenoh.Session, space: keys.KeySpace, config: G1Config) -> None:
        drop = zenoh.CongestionControl.DROP  # as the agent's device publishers: they repeat
        self.config, self.sent = config, 0
        self.low, self.state = (
            session.declare_publisher(
                space.device(keys.G1, config.id, channel), encoding=JSON, congestion_control=drop
            )
            for channel in (keys.LOWSTATE, keys.STATE)
        )
        self.token = session.liveliness().declare_token(
            space.device(keys.G1, config.id, keys.AGENT)
        )
        self.next_s = time.monotonic()

    def tick(self, now: float, t: float) -> None:
        """Put the lowstate and the state when due."""
        if now < self.next_s:
            return
        self.next_s += 1.0 / self.config.relay_hz
        stamp = time.time_ns()
        self.sent += 1
        self.low.put(m.encode(fake_g1_lowstate(t, int(1000 * t), stamp)))
        self.state.put(m.encode(fake_g1_state(self.config, stamp, self.sent)))


def publish(
    inventory: Inventory, rate_hz: float, stop: object, g1_ids: list[str] | None = None
) -> int:
    """Publish until ``stop`` (a threading.Event) is set; returns the joints samples sent."""
    space = keys.KeySpace(inventory.fleet)
    arms = list(inventory.arms)
    g1s = g1_configs(inventory, g1_ids or [])
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
        feeds = [_G1Feed(session, space, config) for config in g1s]
        start = time.monotonic()
        next_tick, next_status = start, start
        while not stop.wait(  # type: ignore[attr-defined]
            max(0.0, min([next_tick, *(f.next_s for f in feeds)]) - time.monotonic())
        ):
            now = time.monotonic()
            for feed in feeds:
                feed.tick(now, now - start)
            if now < next_tick:
                continue
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
        for token in [*tokens, *(f.token for f in feeds)]:
            token.undeclare()
    return sent


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__)
    add_inventory_options(parser)
    parser.add_argument("--rate-hz", type=float, default=10.0)
    parser.add_argument(
        "--g1", action="append", default=[], metavar="ID", help="also a G1 of the inventory"
    )
    args = parser.parse_args(argv)
    inventory = inventory_from_args(args)
    stop = shutdown_event()
    publish(inventory, args.rate_hz, stop, args.g1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
