"""A recording played in the viewer (``fleet viewer --replay FILE.mcap``): a timeline the operator
plays, pauses, scrubs and speeds up, and nothing that could command an arm.

No Zenoh session is opened at all: the recorded samples are fed, in log-time order, through the
same ``ViewerFleet.ingest`` as live samples, so the scene, the table, the arm and device panels
and the event log show a replay exactly as they showed the live fleet: a gripper's opening on
the arm it is mounted on, a G1 posed from its recorded lowstate with its FSM and stop on its
label (the same ``render`` of viewer/scene.py and viewer/g1_scene.py). A recorded payload that
does not decode (a damaged or hostile file) is counted in ``ViewerFleet.malformed``, logged
rate-limited and shown in the replay panel; it is never drawn. Time is the recording's: an
arm's joints age is measured against the replay's position, and an arm is online while its
agent's status is fresh there (a recording holds no liveliness tokens).

Threads: the GUI's callbacks only *ask* (``request_seek``, ``set_playing``, ``set_speed``);
the viewer's render thread applies the requests in ``tick`` and is the only one that moves the
position or feeds samples. Scrubbing backwards rebuilds the state from the start of the file:
ingesting runs at about 200,000 samples a second, so an hour of three arms (about 150,000
samples) rebuilds in under a second.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from fleet.devices import DeviceKind, kinds
from fleet.record.errors import RecordError
from fleet.record.layout import (
    LAYOUT_METADATA,
    FleetLayout,
    devices_from_keys,
    layout_from_keys,
    layout_from_metadata,
)
from fleet.record.reader import Recorded, Recording
from fleet.wire import keys
from viewer.events import EventLog
from viewer.state import DEVICE_SHOWN, INGESTED, Snapshot, ViewerFleet

SPEEDS = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
"""Playback speeds offered (1 = as recorded)."""


@dataclass(frozen=True)
class ReplaySource:
    """What a replay shows: the recording's messages the viewer uses, and where arms and
    devices stand."""

    path: str
    layout: FleetLayout
    messages: tuple[Recorded, ...]
    layout_recorded: bool
    """False: an older recording without a layout; the arms stand in a row."""

    def device_kinds(self) -> dict[str, tuple[DeviceKind, str]]:
        """Device id -> (its kind, the arm it is mounted on or ""), as ``ViewerFleet`` takes
        them live from the inventory."""
        registry = kinds()
        return {d: (registry[p.kind], p.mount) for d, p in self.layout.devices.items()}


def replay_source(recording: Recording) -> ReplaySource:
    """The replay of ``recording``: its layout (recorded, or its arms in a row) and the samples
    of that fleet the viewer shows. Raises RecordError when it holds no arm at all or its
    layout record is malformed."""
    recorded = recording.metadata.get(LAYOUT_METADATA)
    layout = None if recorded is None else layout_from_metadata(recording.path, recorded)
    if layout is None:
        layout = layout_from_keys(r.key for r in recording.messages)
    if layout is None or not layout.arms:
        raise RecordError(f"{recording.path}: no arm's state in this recording: nothing to show")
    if not layout.devices:  # made before devices were laid out: the keys name them
        found = devices_from_keys(layout.fleet, (r.key for r in recording.messages))
        layout = FleetLayout(layout.fleet, layout.arms, found)
    space = keys.KeySpace(layout.fleet)
    fleet_keys = (space.estop, space.reset)
    shown_keys: dict[str, bool] = {}  # a recording has few distinct keys: parse each once

    def shown(key: str) -> bool:
        if key in fleet_keys:
            return True
        if key not in shown_keys:
            try:
                parsed = space.parse_key(key)
            except keys.KeyError_:
                parsed = None
            shown_keys[key] = parsed is not None and _shows(layout, parsed)
        return shown_keys[key]

    messages = tuple(r for r in recording.messages if shown(r.key))
    return ReplaySource(recording.path, layout, messages, recorded is not None)


def _shows(layout: FleetLayout, key: keys.Key) -> bool:
    """An arm's channel the viewer shows, or a laid-out device's state or lowstate."""
    if key.principal:
        return False
    if key.kind == keys.ARM:
        return key.unit in layout.arms and key.channel in INGESTED
    device = layout.devices.get(key.unit)
    return device is not None and device.kind == key.kind and key.channel in DEVICE_SHOWN


class ReplayTimeline:
    """The replay's position, speed and play state, and the fleet state at that position."""

    def __init__(self, source: ReplaySource) -> None:
        self.source = source
        self.arms = tuple(source.layout.arms)
        messages = source.messages
        self.start_ns = messages[0].log_time_ns if messages else 0
        self.end_ns = messages[-1].log_time_ns if messages else 0
        self.duration_s = (self.end_ns - self.start_ns) / 1e9
        self.position_s = 0.0
        self.playing = False
        self.speed = 1.0
        self._fed = 0  # messages[:_fed] are in the state
        self.state = ViewerFleet(
            self.arms,
            source.layout.fleet,
            clock=lambda: self.position_s,
            online_from_status=True,
            devices=source.device_kinds(),
        )
        self._lock = threading.Lock()  # guards the requests below (GUI threads write them)
        self._seek_to: float | None = None
        self._play: bool | None = None
        self._speed: float | None = None
        self._feed_to(0.0)

    @property
    def events(self) -> EventLog:
        """The event log as of the position."""
        return self.state.events

    @property
    def position_wall_ns(self) -> int:
        """The wall-clock time the position corresponds to (when it was recorded)."""
        return self.start_ns + round(self.position_s * 1e9)

    # ------------------------------------------------------------------ requests (any thread)

    def request_seek(self, position_s: float) -> None:
        """Jump to ``position_s`` (clamped to the recording) at the next tick."""
        with self._lock:
            self._seek_to = position_s

    def set_playing(self, playing: bool) -> None:
        """Play or pause from the next tick."""
        with self._lock:
            self._play = playing

    def set_speed(self, speed: float) -> None:
        """Playback speed from the next tick (one of SPEEDS; anything else is ignored)."""
        if speed in SPEEDS:
            with self._lock:
                self._speed = speed

    # ------------------------------------------------------------------ the render thread

    def tick(self, elapsed_s: float) -> None:
        """Apply the requests, then advance by ``elapsed_s`` of wall time if playing (stops at
        the end)."""
        with self._lock:
            seek, play, speed = self._seek_to, self._play, self._speed
            self._seek_to = self._play = self._speed = None
        if speed is not None:
            self.speed = speed
        if play is not None:
            self.playing = play
            if play and self.position_s >= self.duration_s:
                seek = 0.0  # play at the end starts over
        target = self.position_s if seek is None else seek
        if self.playing and seek is None:
            target += elapsed_s * self.speed
        target = min(max(target, 0.0), self.duration_s)
        if target >= self.duration_s and self.playing:
            self.playing = False
        self._feed_to(target)

    def _feed_to(self, position_s: float) -> None:
        if position_s < self.position_s:
            self.state.clear()  # backwards: rebuild from the start
            self._fed = 0
        self.position_s = position_s
        limit = self.start_ns + round(position_s * 1e9)  # a seek to a sample's own time shows it
        messages = self.source.messages
        ingest = self.state.ingest
        while self._fed < len(messages) and messages[self._fed].log_time_ns <= limit:
            record = messages[self._fed]
            at_s = (record.log_time_ns - self.start_ns) / 1e9
            ingest(record.key, record.data, at_s=at_s, wall_ns=record.log_time_ns)
            self._fed += 1

    def snapshot(self) -> Snapshot:
        """The fleet as recorded at the position."""
        return self.state.snapshot()
