"""Fleet state from what the agents publish: pure, fed samples with an injected clock.

An arm is online when its agent's liveliness token is present AND the agent was heard from
(its status, 4 Hz per arm) within ``offline_after_s``. The token goes away at once when
an agent's process dies (its TCP session closes); silence catches a partition, where the
token would only go after the Zenoh lease.
"""

from __future__ import annotations

from dataclasses import dataclass

from fleet.wire import messages as m


@dataclass
class _ArmView:
    token: bool = False
    heard_s: float | None = None
    status: m.ArmStatus | None = None
    status_s: float | None = None
    contact: bool | None = None


@dataclass
class _DeviceView:
    kind: str
    token: bool = False
    heard_s: float | None = None
    link: str = "lost"
    estopped: bool = False
    summary: str | None = None


class FleetStateTracker:
    """The coordinator's view of every arm and device of the inventory (``devices``: id ->
    its kind's key word)."""

    def __init__(
        self, arms: list[str], offline_after_s: float, devices: dict[str, str] | None = None
    ) -> None:
        self.offline_after_s = offline_after_s
        self._arms = {arm: _ArmView() for arm in arms}
        self._devices = {d: _DeviceView(kind) for d, kind in (devices or {}).items()}

    def on_device_token(self, device: str, present: bool, now: float) -> None:
        """A device agent's liveliness token appeared or went away."""
        view = self._devices.get(device)
        if view is not None:
            view.token = present
            if present:
                view.heard_s = now

    def on_device_state(
        self, device: str, link: str, estopped: bool, summary: str, now: float
    ) -> None:
        """A device's latest state (its relay repeats it at least once a second)."""
        view = self._devices.get(device)
        if view is not None:
            view.link, view.estopped, view.summary, view.heard_s = link, estopped, summary, now

    def device_summary(self, device: str, now: float) -> m.DeviceSummary:
        """One device's line of the fleet state."""
        view = self._devices[device]
        heard = None if view.heard_s is None else round(now - view.heard_s, 3)
        online = view.token and heard is not None and heard <= self.offline_after_s
        link = view.link if online and view.link in ("ok", "stale") else "lost"
        return m.DeviceSummary(
            kind=view.kind,
            online=online,
            link=link,  # type: ignore[arg-type]
            estopped=view.estopped,
            summary=view.summary[:256] if view.summary is not None else None,
            heard_age_s=heard,
        )

    def on_token(self, arm: str, present: bool, now: float) -> None:
        """The agent's liveliness token appeared or went away."""
        if arm in self._arms:
            self._arms[arm].token = present
            if present:
                self._arms[arm].heard_s = now

    def on_status(self, arm: str, status: m.ArmStatus, now: float) -> None:
        """The agent's latest status."""
        if arm in self._arms:
            view = self._arms[arm]
            view.status, view.status_s, view.heard_s = status, now, now

    def on_contact(self, arm: str, in_contact: bool) -> None:
        """Contact state (from the contact detector, once it reports)."""
        if arm in self._arms:
            self._arms[arm].contact = in_contact

    def online(self, arm: str, now: float) -> bool:
        """Token present and heard from recently."""
        view = self._arms[arm]
        return (
            view.token and view.heard_s is not None and now - view.heard_s <= self.offline_after_s
        )

    def unready(self, arm: str, now: float) -> str | None:
        """Why ``arm`` cannot take part in a synchronized move now, or None."""
        view = self._arms[arm]
        if not self.online(arm, now):
            return "its agent is offline"
        status = view.status
        if status is None or status.link != "ok":
            return f"its link is {'unknown' if status is None else status.link}"
        if status.estopped:
            return "it is stopped (reset it first)"
        return None

    def summary(self, arm: str, now: float) -> m.ArmSummary:
        """One arm's line of the fleet state."""
        view = self._arms[arm]
        online = self.online(arm, now)
        status = view.status
        heard = None if view.heard_s is None else round(now - view.heard_s, 3)
        if status is None or not online:
            return m.ArmSummary(
                online=online,
                link="lost",
                estopped=bool(status and status.estopped),
                contact=view.contact,
                heard_age_s=heard,
            )
        age = status.feedback_age_s
        if age is not None and view.status_s is not None:
            age = round(age + (now - view.status_s), 3)
        return m.ArmSummary(
            online=True,
            link=status.link,
            enabled=status.enabled,
            powered=status.powered,
            error=status.error,
            estopped=status.estopped,
            contact=view.contact,
            feedback_age_s=age,
            heard_age_s=heard,
        )

    def state(self, coordinator: str, now: float, stamp_ns: int) -> m.FleetState:
        """The whole fleet summary."""
        return m.FleetState(
            stamp_ns=stamp_ns,
            coordinator=coordinator,
            arms={arm: self.summary(arm, now) for arm in self._arms},
            devices={d: self.device_summary(d, now) for d in self._devices},
        )
