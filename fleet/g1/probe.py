"""Which name a G1's LocoClient service answers on (``sport`` or ``loco``). Pure: fed times and
answers, no DDS.

Unitree's SDK names the service ``sport`` for ai_sport >= 8.2 and ``loco`` before; a request
to the other name goes to a topic nobody serves, and the call times out (3104), a stop
included. The inventory's ``service`` picks the name, or ``auto``: the agent asks GetFsmId
(api 7001, served by every firmware) on both names at start, every ``REPEAT_S`` until one
answers, and uses the first that did. With a fixed name it asks too, once answered it stops:
``answered`` tells ``fleet status`` and ``fleet doctor`` whether anybody serves the name.

Until the name is known, commands are refused and stops go to every candidate (a stop to a
name nobody serves costs one unread sample; a stop not sent costs the robot).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fleet.g1.loco import SERVICES

REPEAT_S = 0.5
"""GetFsmId is asked again this often until answered (the first request can precede discovery)."""


@dataclass
class ServiceProbe:
    """The service name of one G1 (``setting``: ``sport``, ``loco`` or ``auto``)."""

    setting: str
    answered: list[str] = field(default_factory=list)
    """The names that answered GetFsmId, first first."""
    asked: int = 0
    _next_s: float | None = None

    def __post_init__(self) -> None:
        if self.setting != "auto" and self.setting not in SERVICES:
            raise ValueError(f"G1 service {self.setting!r} is none of auto, {', '.join(SERVICES)}")

    @property
    def candidates(self) -> tuple[str, ...]:
        """The names asked (both with ``auto``)."""
        return SERVICES if self.setting == "auto" else (self.setting,)

    @property
    def service(self) -> str | None:
        """The name commands go to: the setting, or with ``auto`` the first that answered (None
        while none has)."""
        if self.setting != "auto":
            return self.setting
        return self.answered[0] if self.answered else None

    @property
    def targets(self) -> tuple[str, ...]:
        """Where a stop goes: the known name, else every candidate."""
        service = self.service
        return (service,) if service is not None else self.candidates

    def due(self, now_s: float) -> tuple[str, ...]:
        """The names to ask GetFsmId now (none once answered, or before ``REPEAT_S``)."""
        if self.answered or (self._next_s is not None and now_s < self._next_s):
            return ()
        self._next_s = now_s + REPEAT_S
        self.asked += 1
        return self.candidates

    def answer(self, service: str) -> bool:
        """``service`` answered GetFsmId (any status: somebody serves the name); True when this
        decided the name."""
        if service not in self.candidates or service in self.answered:
            return False
        self.answered.append(service)
        return self.setting == "auto" and len(self.answered) == 1

    def describe(self) -> str:
        """For humans: ``sport (auto: answered GetFsmId)``, ``loco (no answer to GetFsmId
        yet)``, ``auto: no answer on sport, loco yet``."""
        names = ", ".join(self.candidates)
        service = self.service
        if service is None:
            return f"auto: no answer to GetFsmId on {names} yet ({self.asked} asked)"
        how = "auto: " if self.setting == "auto" else ""
        if service in self.answered:
            return f"{service} ({how}answered GetFsmId)"
        return f"{service} (no answer to GetFsmId yet, {self.asked} asked)"
