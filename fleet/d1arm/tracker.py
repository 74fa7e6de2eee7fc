"""What the agent knows about one arm: latest feedback, link state and counters.

Pure bookkeeping with an injected clock (``now`` in monotonic seconds): the agent feeds it every
feedback string and asks it for the link state; nothing here touches DDS or Zenoh.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

from fleet.d1 import protocol as p
from fleet.d1.errors import MalformedMessage, UnknownMessage
from fleet.d1arm.sag import SagCheck
from fleet.devices.safety import ArmSafety
from fleet.inventory import ArmConfig
from fleet.origin.trust import OriginFilter, SampleWriter, SpeedCheck
from fleet.wire.messages import ArmStatus, ContactModel, Diag, LinkState

log = logging.getLogger("fleet.d1arm.tracker")

RATE_WINDOW = 20
"""Feedback rate is measured over the last 20 angle reports (about 2 s)."""
NOMINAL_PERIOD_S = 0.1
"""The D1 reports its angles at about 10 Hz: two reports read together (one DDS take) are still
about this far apart in the arm's time."""
JUMP_MARGIN_DEG = 2.0
"""Noise a report may add on top of the fastest plausible motion."""
PERIODIC: frozenset[type] = frozenset({p.JointAngles, p.D1Status, p.MotorStatus})
"""The reports the arm sends on its own, periodically: one writer each."""
REANCHOR_REPORTS = 3
"""Consecutive reports that agree with each other, but not with the pose before them, are a
real jump (an unloaded arm that fell, a first report after a long gap): the pose follows them."""


@dataclass
class ArmTracker:
    """Latest state of one arm, as decoded from its feedback."""

    config: ArmConfig
    angles_deg: tuple[float, ...] | None = None
    angles_s: float | None = None
    """When ``angles_deg`` was reported (monotonic s): a hold needs a fresh pose."""
    enabled: bool | None = None
    powered: bool | None = None
    error_status: int | None = None
    """The arm's raw ``error_status`` (1 normal, anything else abnormal)."""
    motors_ok: tuple[bool, ...] | None = None
    safety: ArmSafety = field(init=False)
    """The arm's stop latch, lease and watchdog: the one owner of the latch, which the status
    renders."""
    last_feedback_s: float | None = None
    link: LinkState = "lost"
    relayed: int = 0
    malformed: int = 0
    unknown_messages: int = 0
    unknown_fields: int = 0
    rejected: int = 0
    foreign: int = 0
    """Valid-looking reports the arm did not send (dropped): from a writer on another host than
    the arm's, or a second writer of a periodic report the arm's host already sends."""
    implausible: int = 0
    """Angle reports implying a motion faster than the arm can make (dropped: a sensor fault
    or a forgery is never a pose to hold)."""
    commands: int = 0
    ack_timeouts: int = 0
    acks_unmatched: int = 0
    """Acks whose seq named no command we wrote (an arm that answers seq 10): credited to the
    oldest command awaiting that ack (``acks.py``)."""
    acks_foreign: int = 0
    """Acks whose seq is neither one we wrote lately nor 10: credited to no command."""
    acks_ignored: int = 0
    """Acks credited to no command: late or repeated, or with no command awaiting one."""
    last_error: str | None = None
    # The contact detector's model of the arm (set by contact_edge; None: detection disabled)
    contact_model: ContactModel | None = None
    contact_note: str | None = None
    contact_free_moves: int = 0
    contact_model_error_deg: float | None = None
    sag: SagCheck = field(default_factory=SagCheck)
    """Whether the arm holds its pose after an enable (``sag.py``)."""
    _angle_times: deque[float] = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))
    _origins: OriginFilter = field(init=False)
    _speed: SpeedCheck = field(init=False)

    def __post_init__(self) -> None:
        self.safety = ArmSafety(self.config.lease_s, self.config.watchdog_s)
        whose = f"arm {self.config.id!r}"
        self._origins = OriginFilter(whose, self.config.link_lost_s)
        self._speed = SpeedCheck(
            whose,
            self.config.max_speed_deg_s,
            "deg",
            NOMINAL_PERIOD_S,
            JUMP_MARGIN_DEG,
            REANCHOR_REPORTS,
        )

    @property
    def estopped(self) -> bool:
        """A protective stop is latched (read from the latch's one owner)."""
        return self.safety.latched

    def on_feedback(
        self, text: str | bytes, now: float, writer: SampleWriter | None = None
    ) -> p.Decoded | None:
        """Decode one feedback string and update the state; None (and counted) if malformed,
        from a second writer, or an implausible jump."""
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
        message = decoded.message
        if not self._from_the_arm(writer, type(message), now):
            return None
        if isinstance(message, p.JointAngles) and not self._plausible(message.angles_deg, now):
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
            sagging = self.sag.on_angles(message.angles_deg, now)
            if sagging is not None:
                self.last_error = f"arm {self.config.id!r}: {sagging}"
                log.warning("%s", self.last_error)
        elif isinstance(message, p.D1Status):
            self.enabled, self.powered = message.enabled, message.powered
            self.error_status = message.error_status
        elif isinstance(message, p.MotorStatus):
            self.motors_ok = message.motors_ok
        return decoded

    def _from_the_arm(self, writer: SampleWriter | None, kind: type, now: float) -> bool:
        """Whether ``writer`` is one of the arm's own writers for a message of ``kind``
        (``fleet/origin/trust.py``: the arm's host, and on it one writer per periodic report;
        acks from any writer on the host). Seed 000's driver publishes from three services,
        three participants on the arm's card: trust goes to its host, not to one writer."""
        why = self._origins.refusal(writer, kind.__name__, kind in PERIODIC, now)
        if why is None:
            return True
        self.foreign += 1
        self.last_error = why
        return False

    def _plausible(self, angles: tuple[float, ...], now: float) -> bool:
        """False for a report that jumps further than ``max_speed_deg_s`` allows since the
        last accepted one, unless REANCHOR_REPORTS such reports agree with each other."""
        why = self._speed.refusal(angles, now)
        if why is None:
            return True
        self.implausible += 1
        self.last_error = why
        return False

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
        lease = self.safety.holder(now)
        return ArmStatus(
            stamp_ns=stamp_ns,
            link=self.link,
            enabled=self.enabled,
            powered=self.powered,
            error=None if self.error_status is None else self.error_status != 1,
            error_status=self.error_status,
            motors_ok=None if self.motors_ok is None else list(self.motors_ok),
            estopped=self.safety.latched,
            feedback_age_s=None if age is None else round(age, 3),
            stop_reason=self.safety.stop_reason,
            owner=None if lease is None else lease.owner,
            owned_s=None if lease is None else round(now - lease.since_s, 1),
            lease_left_s=None if lease is None else round(lease.expires_s - now, 1),
            contact_model=self.contact_model,
            watched_by=self.safety.watched_by,
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
            foreign_feedback=self.foreign,
            implausible_feedback=self.implausible,
            commands=self.commands,
            ack_timeouts=self.ack_timeouts,
            acks_unmatched=self.acks_unmatched,
            acks_ignored=self.acks_ignored,
            acks_foreign=self.acks_foreign,
            feedback_rate_hz=round(self.feedback_rate_hz(), 2),
            last_feedback_age_s=None if age is None else round(age, 3),
            last_error=self.last_error,
            contact_model=self.contact_note,
            contact_free_moves=self.contact_free_moves,
            contact_model_error_deg=self.contact_model_error_deg,
        )
