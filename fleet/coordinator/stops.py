"""The coordinator's record of latched stops (repeated in every heartbeat) and of their
fan-out timings (from the agents' acknowledgments). Pure."""

from __future__ import annotations

from dataclasses import dataclass, field

from fleet.wire import messages as m

FLEET = "*"


@dataclass
class _Fanout:
    request: m.StopRequest
    acks: dict[str, m.StopAck] = field(default_factory=dict)


class StopBook:
    """Which stops are latched, and how each one fanned out."""

    def __init__(self, arms: list[str], keep: int = 32, devices: list[str] | None = None) -> None:
        self._arms = frozenset(arms)
        self._acking = self._arms | frozenset(devices or ())
        """Arms and devices: both acknowledge a fleet stop and are in its report;
        the latch bookkeeping (per-target stops, resets one by one) is the arms'."""
        self._latched: dict[str, m.StopRequest] = {}
        self._reset_since_fleet_stop: set[str] = set()
        self._fanouts: dict[str, _Fanout] = {}
        self._keep = keep

    def on_stop(self, target: str, request: m.StopRequest) -> bool:
        """A stop was put on the fleet key (``target`` = ``*``) or on one arm's key.
        The newest stop per target is the one the heartbeat repeats. A stop for an arm that is
        not in the inventory is not recorded (False): no agent serves it, and a flood of
        invented names must not grow the heartbeat."""
        if target != FLEET and target not in self._arms:
            return False
        self._latched[target] = request
        if target == FLEET:
            self._reset_since_fleet_stop.clear()
        if request.stop_id not in self._fanouts:
            self._fanouts[request.stop_id] = _Fanout(request)
            while len(self._fanouts) > self._keep:
                del self._fanouts[next(iter(self._fanouts))]
        return True

    def knows(self, stop_id: str) -> bool:
        """True when the fan-out of ``stop_id`` is on record (a repeat of a known stop)."""
        return stop_id in self._fanouts

    def on_reset(self, target: str) -> None:
        """A reset of the fleet (``*``: clears everything) or of one arm."""
        if target == FLEET:
            self._latched.clear()
            return
        if target not in self._arms:
            return
        self._latched.pop(target, None)
        self._reset_since_fleet_stop.add(target)
        if self._reset_since_fleet_stop.issuperset(self._arms):
            self._latched.pop(FLEET, None)  # every arm was reset one by one

    def latched(self) -> dict[str, m.StopRequest]:
        """The stops the heartbeat repeats."""
        return dict(self._latched)

    def on_ack(self, arm: str, ack: m.StopAck) -> m.StopReport | None:
        """Record the ack published on ``arm``'s key (the key says which arm, not the payload);
        returns the updated report of that stop (None if the stop or the arm is unknown)."""
        fanout = self._fanouts.get(ack.stop_id)
        if fanout is None or arm not in self._acking:
            return None
        fanout.acks[arm] = ack
        return self.report(ack.stop_id)

    def report(self, stop_id: str) -> m.StopReport | None:
        """Per-arm timings of one stop, in ms from the stop's stamp."""
        fanout = self._fanouts.get(stop_id)
        if fanout is None:
            return None
        t0 = fanout.request.stamp_ns

        def ms(t: int | None) -> float | None:
            return None if t is None else round((t - t0) / 1e6, 3)

        return m.StopReport(
            stop_id=stop_id,
            source=fanout.request.source,
            stamp_ns=t0,
            arms={
                arm: m.StopTiming(ms(a.received_ns), ms(a.dds_written_ns), ms(a.still_ns))
                for arm, a in fanout.acks.items()
            },
        )
