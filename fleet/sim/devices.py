"""Simulated devices beside the arms (``fleet/devices``: Dex1-1 grippers, G1s), on real DDS.

One thread serves every simulated device of the process: it waits on a DDS WaitSet over their
command readers (and a guard condition that ``close`` triggers) until the next state sample is
due, takes the commands, and publishes what is due. Each kind's simulator object
(``DeviceKind.sim``) gives ``readers``, ``on_data(index, now_s)`` and ``step(now_s) -> next``.
In a process that simulates arms too, it shares their DDS participant (CycloneDDS takes one
configuration per domain and process).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from cyclonedds.core import (
    GuardCondition,
    InstanceState,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.util import duration

from fleet.d1 import dds
from fleet.devices import kind_of
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory

log = logging.getLogger("fleet.sim.devices")

_ANY = SampleState.Any | ViewState.Any | InstanceState.Any
MAX_WAIT_S = 0.05


class SimulatedDevices:
    """The simulated devices ``device_ids`` of ``inventory``. A context manager."""

    def __init__(
        self, inventory: Inventory, device_ids: list[str], participant: Any = None
    ) -> None:
        self._channel = None
        if participant is None:
            self._channel = dds.DdsChannel(*inventory.device_network(device_ids))
            participant = self._channel.participant
        self._stop = threading.Event()
        self._guard_condition = GuardCondition(participant)
        self._waitset = WaitSet(participant)
        self._waitset.attach(self._guard_condition)
        now = time.monotonic()
        self.devices: list[Any] = []
        for device_id in device_ids:
            config = inventory.device(device_id)
            sim = kind_of(config).load("sim")(config, participant, now)
            for reader in sim.readers:
                self._waitset.attach(ReadCondition(reader, _ANY))
            self.devices.append(sim)
        self.guard = ThreadGuard("fleet sim devices")
        self._thread = self.guard.thread(self._run, "sim-devices")

    def start(self) -> SimulatedDevices:
        """Start the loop."""
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            next_s = min((d.next_s for d in self.devices), default=now + MAX_WAIT_S)
            timeout = min(MAX_WAIT_S, max(0.0, next_s - now))
            if timeout > 0:
                self._waitset.wait(duration(seconds=timeout))
            now = time.monotonic()
            for device in self.devices:
                for index in range(len(device.readers)):
                    device.on_data(index, now)
                if device.next_s <= now:
                    device.step(now)

    def close(self) -> None:
        """Stop the loop, then delete the DDS entities (idempotent)."""
        self._stop.set()
        self._guard_condition.set(True)
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for device in self.devices:
            log.info("simulated %s: %s", device.device, getattr(device, "summary", lambda: "")())
        if self._channel is not None:
            self._channel.close()
            self._channel = None

    def __enter__(self) -> SimulatedDevices:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
