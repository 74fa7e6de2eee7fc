"""What the agent knows about one arm: latest feedback, link state and counters.

Pure bookkeeping with an injected clock (``now`` in monotonic seconds): the agent feeds it every
feedback string and asks it for the link state; nothing here touches DDS or Zenoh.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from fleet.d1 import protocol as p
from fleet.d1.errors import MalformedMessage, UnknownMessage
from fleet.inventory import ArmConfig
from fleet.wire.messages import ArmStatus, Diag, LinkState

RATE_WINDOW = 20
"""Feedback rate is measured over the last 20 angle reports (about 2 s)."""


@dataclass
class ArmTracker:
    """Latest state of one arm, as decoded from its feedback."""

    config: ArmConfig
    angles_deg: tuple[float, ...] | None = None
    angles_s: float | None = None
    """When ``angles_deg`` was reported (monotonic s): a hold needs a fresh pose."""
    enabled: bool | None = None
    powered: bool | None = None
    error: bool | None = None
    motors_ok: tuple[bool, ...] | None = None
    estopped: bool = False
    stop_reason: str | None = None
    last_feedback_s: float | None = None
    link: LinkState = "lost"
    relayed: int = 0
    malformed: int = 0
    unknown_messages: int = 0
    unknown_fields: int = 0
    rejected: int = 0
    commands: int = 0
    ack_timeouts: int = 0
    last_error: str | None = None
    _angle_times: deque[float] = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))

    def on_feedback(self, text: str | bytes, now: float) -> p.Decoded | None:
        """Decode one feedback string and update the state; None (and counted) if malformed."""
        try:
            decoded = p.decode_message(text)
        except UnknownMessage as exc:
            self.unknown_messages += 1
            self.last_error = str(exc)
            return None
        except MalformedMessage as exc:
            self.malformed += 1
            self.last_error = f"malformed feedback: {exc}"
            return None
        self.relayed += 1
        self.last_feedback_s = now
        if decoded.unknown_fields:
            self.unknown_fields += len(decoded.unknown_fields)
        message = decoded.message
        if isinstance(message, p.JointAngles):
            self.angles_deg = message.angles_deg
            self.angles_s = now
            self._angle_times.append(now)
        elif isinstance(message, p.ArmStatus):
            self.enabled, self.powered, self.error = message.enabled, message.powered, message.error
        elif isinstance(message, p.MotorStatus):
            self.motors_ok = message.motors_ok
        return decoded

    def update_link(self, now: float) -> bool:
        """Recompute the link state from the feedback age; True when it changed."""
        age = self.feedback_age_s(now)
        if age is None or age > self.config.link_lost_s:
            link: LinkState = "lost"
        elif age > self.config.link_stale_s:
            link = "stale"
        else:
            link = "ok"
        changed = link != self.link
        self.link = link
        return changed

    def feedback_age_s(self, now: float) -> float | None:
        """Seconds since the last valid feedback message, None if never."""
        return None if self.last_feedback_s is None else max(0.0, now - self.last_feedback_s)

    def feedback_rate_hz(self) -> float:
        """Angle reports per second over the recent window."""
        times = self._angle_times
        if len(times) < 2 or times[-1] <= times[0]:
            return 0.0
        return (len(times) - 1) / (times[-1] - times[0])

    def status(self, now: float, stamp_ns: int) -> ArmStatus:
        """The ``arm/<arm>/status`` payload."""
        age = self.feedback_age_s(now)
        return ArmStatus(
            stamp_ns=stamp_ns,
            link=self.link,
            enabled=self.enabled,
            powered=self.powered,
            error=self.error,
            motors_ok=None if self.motors_ok is None else list(self.motors_ok),
            estopped=self.estopped,
            feedback_age_s=None if age is None else round(age, 3),
            stop_reason=self.stop_reason if self.estopped else None,
        )

    def diag(self, now: float, stamp_ns: int) -> Diag:
        """The ``arm/<arm>/diag`` payload."""
        age = self.feedback_age_s(now)
        return Diag(
            stamp_ns=stamp_ns,
            link=self.link,
            relayed=self.relayed,
            malformed=self.malformed,
            unknown_messages=self.unknown_messages,
            unknown_fields=self.unknown_fields,
            rejected=self.rejected,
            commands=self.commands,
            ack_timeouts=self.ack_timeouts,
            feedback_rate_hz=round(self.feedback_rate_hz(), 2),
            last_feedback_age_s=None if age is None else round(age, 3),
            last_error=self.last_error,
        )
