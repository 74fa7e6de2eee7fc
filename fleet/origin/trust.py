"""Which writers of one robot's state the agent trusts, and which readings are possible: pure,
with an injected clock (monotonic seconds), one policy for every kind.

Any participant on a robot's DDS network can write its state topics (DDS has no
authentication). A forged state must never become what the agent holds: a stop's hold targets
the measured position, so a forged one drives the real robot to it (``tests/netlab/
test_rogue_dds.py``). Two checks, each used by the D1 arm's tracker and by the device drivers:

- ``OriginFilter``: trust goes to the robot's *host* (the host of the first writer heard,
  ``directory.py`` names it), kept while the robot speaks from it; a replaced robot's host takes
  over once the old one was silent for the window (``link_lost_s``, a device's stale window).
  On that host each periodic report (a D1's angles, status and motors; a device's state topics)
  has one writer, the first heard, kept while it speaks: a second writer, even beside the
  robot's own services, is foreign. Non-periodic messages (a D1's acks) may come from any writer
  on the host (one service acks a move, another an enable).
- ``SpeedCheck``: a reading implying a motion faster than the robot can make is a sensor fault
  or a forgery, dropped, unless a few readings in a row agree with each other (a real jump: an
  unloaded arm that fell, a first reading after a gap).

Both answer None (trusted) or why not, in words for the unit's ``last_error``; the caller counts
(``foreign``, ``implausible``) beside its other counters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass(frozen=True)
class SampleWriter:
    """One DDS writer of a robot's state or feedback topic."""

    handle: int
    host: str | None
    """Host name and addresses of its participant (None: it announced none)."""


@dataclass
class OriginFilter:
    """Which writers are the robot's own (see the module docstring). One per robot; not
    thread-safe (the relay thread feeds it)."""

    whose: str
    """The robot, for messages: ``"arm 'a1'"``, ``"gripper 'gl'"``."""
    window_s: float
    """Silence after which the robot's host, or a report's writer, may change."""
    _host: str | None = None
    _host_s: float | None = None
    """The robot's host (of the first writer heard) and when the robot last spoke from it."""
    _owners: dict[str, tuple[int, float]] = field(default_factory=dict)
    """Periodic report -> the handle of the writer that sends it and when it last did."""

    def refusal(
        self, writer: SampleWriter | None, report: str, periodic: bool, now: float
    ) -> str | None:
        """None when ``writer`` is one of the robot's own writers of ``report`` (a writer
        unknown to the caller, None, is trusted: nothing to compare), else why not."""
        if writer is None:
            return None
        if self._host_s is None or now - self._host_s > self.window_s:
            self._host, self._owners = writer.host, {}
        if writer.host != self._host:
            return self._foreign(f"{report} from host {writer.host!r}, not its {self._host!r}")
        if periodic:
            owner = self._owners.get(report)
            if owner is not None and owner[0] != writer.handle and now - owner[1] <= self.window_s:
                return self._foreign(f"{report} from a second writer on its host")
            self._owners[report] = (writer.handle, now)
        self._host_s = now
        return None

    def _foreign(self, what: str) -> str:
        return f"{self.whose}: {what} was ignored (a rogue participant on its DDS network?)"


@dataclass
class SpeedCheck:
    """Readings (one value per joint) that move no faster than ``max_speed`` per second since
    the last accepted one; not thread-safe (the relay thread feeds it)."""

    whose: str
    max_speed: float
    """Units per second (deg/s for a D1, rad/s for a gripper)."""
    unit: str
    nominal_period_s: float
    """The robot's report period: two reports read together are still about this far apart in
    the robot's time."""
    margin: float
    """Noise a report may add on top of the fastest motion."""
    reanchor: int
    """Consecutive reports that agree with each other, but not with the one before them, are a
    real jump: the reading follows them."""
    last: tuple[float, ...] | None = None
    last_s: float | None = None
    """The last accepted reading and when (monotonic s)."""
    _jumps: list[tuple[tuple[float, ...], float]] = field(default_factory=list)

    def refusal(self, values: Sequence[float], now: float) -> str | None:
        """None (and ``values`` accepted) when plausible, else why not."""
        reading = tuple(values)
        last, last_s = self.last, self.last_s
        if last is None or last_s is None or self._within(reading, last, now - last_s):
            self._jumps.clear()
            self.last, self.last_s = reading, now
            return None
        if self._jumps:
            previous, previous_s = self._jumps[-1]
            if not self._within(reading, previous, now - previous_s):
                self._jumps.clear()
        self._jumps.append((reading, now))
        if len(self._jumps) >= self.reanchor:
            self._jumps.clear()
            self.last, self.last_s = reading, now
            return None
        return (
            f"{self.whose}: a reading jumped {jump(reading, last):.3g} {self.unit}, faster than "
            f"{self.max_speed:g} {self.unit}/s: ignored (a sensor fault or a forgery)"
        )

    def _within(self, reading: tuple[float, ...], before: tuple[float, ...], dt_s: float) -> bool:
        limit = self.max_speed * max(dt_s, self.nominal_period_s)
        return jump(reading, before) <= limit + self.margin


def jump(a: Sequence[float], b: Sequence[float]) -> float:
    """The largest difference of one joint between two readings."""
    return max((abs(x - y) for x, y in zip(a, b, strict=False)), default=0.0)
