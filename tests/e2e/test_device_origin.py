"""A rogue DDS participant on a device's network writes forged states (with Unitree's own IDL
classes from PyPI, ``unitree-dds-wrapper``: a far side nobody here wrote) while the device
stands still: the agent relays only the device's own state, counts the forged samples as
``foreign``, and a stop still stops, holds the real position and is confirmed by the real
state.

Before: a device driver took every sample on its state topic from any writer. A gripper's stop
holds its measured position, so a forged "fully closed" state made the stop close the real
gripper (the arm's bug, ``tests/netlab/test_rogue_dds.py``); a G1's forged "dynamic" state kept
its stop from being confirmed, a forged "static" one confirmed a stop that was not done.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from fleet.d1 import dds
from fleet.devices import kind_of
from fleet.wire import keys
from fleet.wire.payloads import DIAG
from testkit.collect import Collector
from testkit.harness import wait_until
from testkit.kinds import KINDS, Kind, devices_fleet

pytest.importorskip("unitree_dds_wrapper.idl")
from unitree_dds_wrapper.idl.unitree_go.msg import dds_ as go  # noqa: E402
from unitree_dds_wrapper.idl.unitree_hg.msg import dds_ as hg  # noqa: E402

DEVICE_KINDS = [k for k in KINDS if not k.is_arm]
FORGED_PERIOD_S = 0.005
"""The rogue writes 200 forged states a second."""
FORGED_SAMPLES = 100
"""Forged samples counted before the stop (half a second of the flood)."""


def _forgery(kind: Kind, real: Any) -> tuple[str, type, Callable[[], Any], Callable[[Any], bool]]:
    """(topic, Unitree IDL class, a forged state, whether a relayed state shows the forgery)."""
    if kind.name == "gripper":  # fully closed, against a gripper that stands open
        forged_q = 0.0 if real.q_rad > 1.0 else 6.0
        return (
            "rt/dex1/left/state",
            go.MotorStates_,
            lambda: go.MotorStates_(states=[go.MotorState_(q=forged_q, temperature=30)]),
            lambda state: abs(state.q_rad - forged_q) < 0.5,
        )
    forged_fsm = 801 if real.fsm_id != 801 else 500  # "run", walking (dynamic)
    return (
        "rt/sportmodestate",
        hg.SportModeState_,
        lambda: hg.SportModeState_(fsm_id=forged_fsm, fsm_mode=1, task_time=0.0),
        lambda state: state.fsm_id == forged_fsm,
    )


@contextmanager
def _rogue(domain: int, topic: str, idl: type, make: Callable[[], Any]) -> Iterator[None]:
    """A second DDS participant writing ``make()`` every ``FORGED_PERIOD_S`` (bounded)."""
    channel = dds.DdsChannel(domain, "lo")
    stop = threading.Event()
    try:
        writer = DataWriter(channel.participant, Topic(channel.participant, topic, idl))
        wait_until(lambda: writer.get_publication_matched_status().current_count >= 1, 10.0)

        def run() -> None:
            deadline = time.monotonic() + 60.0  # bounded, whatever the test does
            while not stop.wait(FORGED_PERIOD_S) and time.monotonic() < deadline:
                writer.write(make())

        thread = threading.Thread(target=run, name="rogue", daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join(timeout=5.0)
    finally:
        channel.close()


@pytest.mark.parametrize("kind", DEVICE_KINDS, ids=[k.name for k in DEVICE_KINDS])
def test_forged_device_state_is_foreign_and_a_stop_holds_the_real_one(
    tmp_path: Path, kind: Kind
) -> None:
    with devices_fleet(tmp_path) as h:
        client = h.client()
        decode = kind_of(client.inventory.device(kind.unit)).payloads[keys.STATE].decode
        states = Collector(client.session, client.unit_key(kind.unit, keys.STATE), decode)
        diags = Collector(client.session, client.unit_key(kind.unit, keys.DIAG), DIAG.decode)
        wait_until(lambda: (s := states.latest()) is not None and s.link == "ok", 30.0)
        wait_until(lambda: diags.latest() is not None, 10.0)
        real = states.latest()
        topic, idl, make, shows_forgery = _forgery(kind, real)
        with _rogue(h.domain, topic, idl, make):
            wait_until(
                lambda: (d := diags.latest()) is not None and d.foreign_feedback >= FORGED_SAMPLES,
                15.0,
            )
            acks = client.estop(kind.unit, reason="rogue participant", timeout_s=5.0)
            ack = next(iter(acks.values()))
            assert ack is not None and ack.done and ack.confirmed_ns is not None, acks
            confirmed = len(states)
            wait_until(lambda: len(states) > confirmed + 5, 5.0)  # relayed under the stop too
        relayed = states.items
        assert relayed and not [s for s in relayed if shows_forgery(s)], relayed[-3:]
        latest = states.latest()
        assert latest is not None and latest.estopped and latest.link == "ok", latest
        if kind.name == "gripper":  # the stop holds the real position, not the forged one
            assert latest.target_rad == pytest.approx(real.q_rad, abs=0.05), latest
            assert latest.q_rad == pytest.approx(real.q_rad, abs=0.05), latest
        diag = diags.latest()
        assert diag is not None and diag.foreign_feedback >= FORGED_SAMPLES, diag
        assert diag.implausible_feedback == 0, diag  # the origin filter caught every one
        assert diag.last_error is not None and "rogue participant" in diag.last_error, diag
        print(
            f"\n{kind.name}: {diag.foreign_feedback} forged samples foreign, "
            f"{len(relayed)} states relayed, none forged; stop confirmed in "
            f"{(ack.confirmed_ns - ack.received_ns) / 1e6:.0f} ms"
        )
