"""A unit's status/state and diag -> one diagnostic_msgs/DiagnosticStatus. Pure.

Level: ERROR when the link is lost or the arm reports an error, WARN when stopped or the link is
stale (or nothing was heard yet), OK otherwise. ``name`` is ``<fleet>/<id>``, ``hardware_id``
the unit's id; ``values`` carry the diag counters and the status fields, as text.
"""

from __future__ import annotations

from typing import Any

import msgspec

from fleet.ros2.messages import ERROR, OK, STALE, WARN, Status


def _values(*parts: Any) -> tuple[tuple[str, str], ...]:
    out: list[tuple[str, str]] = []
    for part in parts:
        if part is None:
            continue
        for key, value in msgspec.structs.asdict(part).items():
            if isinstance(value, (str, int, float, bool)) or value is None:
                out.append((key, "" if value is None else str(value)))
    return tuple(out)


def _level(link: str | None, error: bool, stopped: bool) -> tuple[int, str]:
    if link is None:
        return STALE, "no status heard yet"
    if link == "lost" or error:
        return ERROR, "link lost" if link == "lost" else "the arm reports an error"
    if link != "ok":
        return WARN, f"link {link}"
    if stopped:
        return WARN, "protective stop latched"
    return OK, "ok"


def arm_status(unit: str, kind: str, status: Any, diag: Any, fleet: str) -> Status:
    """The DiagnosticStatus of arm ``unit`` from its latest ArmStatus (or None) and a Diag."""
    link = None if status is None else status.link
    error = bool(status is not None and status.error)
    stopped = bool(status is not None and status.estopped)
    level, message = _level(link, error, stopped)
    return Status(level, f"{fleet}/{unit}", message, unit, _values(diag, status))


def device_status(unit: str, kind: str, state: Any, diag: Any, fleet: str) -> Status:
    """The DiagnosticStatus of a device (gripper, G1) from its latest state and a Diag."""
    link = None if state is None else state.link
    error = bool(state is not None and getattr(state, "error", False))
    stopped = bool(state is not None and state.estopped)
    level, message = _level(link, error, stopped)
    return Status(level, f"{fleet}/{unit}", f"{kind}: {message}", unit, _values(diag, state))
