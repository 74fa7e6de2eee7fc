"""What the agent knows about one arm: latest feedback, link state and counters.

Pure bookkeeping with an injected clock (``now`` in monotonic seconds): the agent feeds it every
feedback string and asks it for the link state; nothing here touches DDS or Zenoh.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

from edge_agent.origins import FeedbackWriter
from edge_agent.safety import ArmSafety
from edge_agent.sag import SagCheck
from fleet.d1 import protocol as p
from fleet.d1.errors import MalformedMessage, UnknownMessage
from fleet.inventory import ArmConfig
from fleet.wire.messages import ArmStatus, ContactModel, Diag, LinkState

log = logging.getLogger("edge_agent.tracker")

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
    _host: str | None = None
    _host_s: float | None = None
    """The arm's host (of the first writer heard) and when the arm last spoke from it."""
    _owners: dict[type, tuple[FeedbackWriter, float]] = field(default_factory=dict)
    """Periodic report kind -> the writer that sends it and when it last did."""
    _jumps: list[tuple[tuple[float, ...], float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.safety = ArmSafety(self.config.lease_s, self.config.watchdog_s)

    @property
    def estopped(self) -> bool:
        """A protective stop is latched (read from the latch's one owner)."""
        return self.safety.latched

    def on_feedback(
        self, text: str | bytes, now: float, writer: FeedbackWriter | None = None
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

    def _from_the_arm(self, writer: FeedbackWriter | None, kind: type, now: float) -> bool:
        """Whether ``writer`` is one of the arm's own writers for a message of ``kind``.

        The arm publishes its feedback from several services (seed 000: three participants on
        its card), so trust goes to its *host*: the host of the first writer heard, kept while
        the arm speaks from it (a replaced arm's host takes over once the old one was silent
        for ``link_lost_s``). On that host each periodic report (angles, status, motors) has
        one writer, the first heard, kept while it speaks: a second writer of angles even on
        the arm's own host (a rogue process beside the arm's services) is foreign. Acks may
        come from any writer on the arm's host (one service acks a move, another an enable).
        The speed-plausibility check (``_plausible``) still runs on what is accepted."""
        if writer is None:
            return True
        lost = self.config.link_lost_s
        if self._host_s is None or now - self._host_s > lost:
            self._host, self._owners = writer.host, {}
        if writer.host != self._host:
            return self._foreign(f"from host {writer.host!r}, not the arm's {self._host!r}")
        if kind in PERIODIC:
            owner = self._owners.get(kind)
            if owner is not None and owner[0].handle != writer.handle and now - owner[1] <= lost:
                return self._foreign(f"a second writer of {kind.__name__} on the arm's host")
            self._owners[kind] = (writer, now)
        self._host_s = now
        return True

    def _foreign(self, why: str) -> bool:
        self.foreign += 1
        self.last_error = f"feedback {why} was ignored (a rogue participant on the arm's network?)"
        return False

    def _plausible(self, angles: tuple[float, ...], now: float) -> bool:
        """False for a report that jumps further than ``max_speed_deg_s`` allows since the
        last accepted one, unless REANCHOR_REPORTS such reports agree with each other."""
        last, last_s = self.angles_deg, self.angles_s
        if last is None or last_s is None:
            return True
        limit = self.config.max_speed_deg_s * max(now - last_s, NOMINAL_PERIOD_S)
        if _jump(angles, last) <= limit + JUMP_MARGIN_DEG:
            self._jumps.clear()
            return True
        if self._jumps:
            previous, previous_s = self._jumps[-1]
            step = self.config.max_speed_deg_s * max(now - previous_s, NOMINAL_PERIOD_S)
            if _jump(angles, previous) > step + JUMP_MARGIN_DEG:
                self._jumps.clear()
        self._jumps.append((angles, now))
        if len(self._jumps) >= REANCHOR_REPORTS:
            self._jumps.clear()
            return True
        self.implausible += 1
        self.last_error = (
            f"an angle report jumped {_jump(angles, last):.0f} deg, faster than "
            f"{self.config.max_speed_deg_s:g} deg/s: ignored (a sensor fault or a forgery)"
        )
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
            stop_reason=self.safety.last_reason if self.safety.latched else None,
            owner=None if lease is None else lease.owner,
            owned_s=None if lease is None else round(now - lease.since_s, 1),
            lease_left_s=None if lease is None else round(lease.expires_s - now, 1),
            contact_model=self.contact_model,
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


def _jump(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return max((abs(x - y) for x, y in zip(a, b, strict=False)), default=0.0)
