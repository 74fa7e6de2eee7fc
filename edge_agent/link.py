"""The agent's DDS side and its relay thread: one participant for its (domain, interface), the
kinds' readers and writers created on it once, at start-up (a served kind's ``LinkPart``,
``fleet/devices/served.py``: the D1 arms' feedback readers and command writers; a device
kind's driver, ``fleet/devices/driver.py``), and the ``relay`` thread.

The relay thread waits on a DDS WaitSet over one ReadCondition per reader of every kind. The
wait is done in CycloneDDS's C core and names the readers that have data, so a sample costs no
Python on DDS's own receive thread, no queue and no second thread: this thread takes every
ready sample of every ready reader in one wake-up, through the taker its part bound to that
reader at start-up (an arm's hands each sample to its server, which decodes it and puts it on
Zenoh). (The Python listener it replaces cost about 100 us of CPU per sample at 100 arms: a
crossing into Python on the receive thread, then a hand-off.) Between samples the same thread
runs the agent's periodic jobs (``on_tick`` every ``tick_s``) and each device driver's ``tick``
when the time it asked for comes (a gripper polls its 500 Hz state there, at its relay rate);
after a driver's data or tick the agent checks its stop (``on_device``). A flood from a rogue
participant costs no memory: each reader keeps at most its history depth. Entities are never
created or deleted after start-up. Writers are created once: Unitree's SDK waits for discovery
when a writer is created, which a stop cannot afford.
"""

from __future__ import annotations

import ctypes
import threading
import time
from collections.abc import Callable

from cyclonedds.core import (
    DDSException,
    GuardCondition,
    InstanceState,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.sub import DataReader

from fleet.d1 import dds
from fleet.devices.driver import DeviceDriver
from fleet.devices.served import LinkPart
from fleet.guard import ThreadGuard
from fleet.inventory import DdsNetwork
from fleet.origin.directory import WriterDirectory

TickHandler = Callable[[float], None]
"""(monotonic now): the periodic jobs."""
DeviceHandler = Callable[[str, float], None]
"""(device id, monotonic now): after its driver took data or ticked."""
DEVICE_TICK_MAX_S = 0.1
"""Every driver ticks at least this often (it asks for more)."""


class ReadySet:
    """A DDS WaitSet whose ``wait`` returns which of ``readers`` have unread samples.

    The binding's ``WaitSet.wait`` only counts the triggered entities; this attaches each
    reader's ReadCondition with its index as the attach value and asks the C core for them.
    A GuardCondition (index ``len(readers)``) wakes the wait on close.
    """

    def __init__(self, participant: object, readers: list[DataReader]) -> None:
        self._waitset = WaitSet(participant)  # type: ignore[arg-type]
        self._closing = GuardCondition(participant)  # type: ignore[arg-type]
        self._conditions = [
            ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any)
            for reader in readers
        ]
        for index, entity in [*enumerate(self._conditions), (len(readers), self._closing)]:
            self._attach(entity, index)
        self._triggered = (ctypes.c_void_p * (len(readers) + 1))()
        self._count = len(readers)

    def _attach(self, entity: ReadCondition | GuardCondition, index: int) -> None:
        waitset = self._waitset
        ret = waitset._waitset_attach(waitset._ref, entity._ref, index)
        if ret < 0:
            raise DDSException(ret, f"attaching {entity!r} to the relay's WaitSet")
        waitset.attached.append((entity, None))  # the binding detaches these on deletion

    def wait(self, timeout_s: float) -> list[int]:
        """Block up to ``timeout_s`` (GIL released); the indices of the readers with data."""
        waitset = self._waitset
        count = waitset._waitset_wait(
            waitset._ref, self._triggered, len(self._triggered), max(0, int(timeout_s * 1e9))
        )
        if count < 0:
            raise DDSException(count, "waiting on the relay's WaitSet")
        # A void* attach value comes back as None for 0.
        indices = [self._triggered[i] or 0 for i in range(count)]
        return [index for index in indices if index < self._count]

    def wake(self) -> None:
        """Make the current or next ``wait`` return at once."""
        self._closing.set(True)


class DdsLink:
    """The DDS side of the agent on one domain and interface: every kind's readers, one
    relay thread."""

    def __init__(
        self, network: DdsNetwork, on_tick: TickHandler, tick_s: float, guard: ThreadGuard
    ) -> None:
        self._channel = dds.DdsChannel(*network)
        self.participant = self._channel.participant
        self._on_tick = on_tick
        self._tick_s = tick_s
        self._parts: list[LinkPart] = []
        self._drivers: dict[str, DeviceDriver] = {}
        self._on_device: DeviceHandler = lambda _device, _now: None
        self._ready: ReadySet | None = None
        self.directory = WriterDirectory(self.participant)
        """Who wrote a sample (every kind's readings; relay thread)."""
        self._stop = threading.Event()
        self._thread = guard.thread(self._run, "relay")

    def add_part(self, part: LinkPart) -> None:
        """Take ``part``'s readers on the relay thread too (before ``start``)."""
        self._parts.append(part)

    def add_drivers(self, drivers: dict[str, DeviceDriver], on_device: DeviceHandler) -> None:
        """Serve ``drivers`` on the relay thread too (before ``start``)."""
        self._drivers = dict(drivers)
        self._on_device = on_device

    @property
    def write_failures(self) -> int:
        """DDS writes the parts' writers refused since start (the agent's diag)."""
        return sum(part.write_failures for part in self._parts)

    def start(self) -> None:
        """Start relaying feedback and running the periodic jobs."""
        sources = [source for part in self._parts for source in part.readers]
        readers = [reader for reader, _take in sources]
        self._takers = [take for _reader, take in sources]
        self._device_readers: list[tuple[str, DeviceDriver, int]] = []
        for device, driver in self._drivers.items():
            for index, reader in enumerate(driver.readers):
                readers.append(reader)
                self._device_readers.append((device, driver, index))
        self._ready = ReadySet(self.participant, readers)
        self._thread.start()

    def _run(self) -> None:
        assert self._ready is not None
        takers = self._takers
        parts = len(takers)
        next_tick = time.monotonic()
        due = dict.fromkeys(self._drivers, next_tick)
        while not self._stop.is_set():
            wake = min(next_tick, *due.values()) if due else next_tick
            ticked: set[str] = set()
            for index in self._ready.wait(wake - time.monotonic()):
                if index < parts:
                    takers[index]()
                    continue
                device, driver, local = self._device_readers[index - parts]
                driver.on_data(local, time.monotonic())
                ticked.add(device)
            now = time.monotonic()
            for device, driver in self._drivers.items():
                if device in ticked or now >= due[device]:
                    due[device] = min(driver.tick(now), now + DEVICE_TICK_MAX_S)
                    self._on_device(device, now)
            if now >= next_tick:
                next_tick = max(next_tick + self._tick_s, now)
                self._on_tick(now)

    def close(self) -> None:
        """Stop the thread, then delete the participant (idempotent)."""
        self._stop.set()
        if self._ready is not None:
            self._ready.wake()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._channel.close()
