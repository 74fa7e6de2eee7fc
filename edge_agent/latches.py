"""Latched stops that survive an agent restart: one small file per stopped arm.

An agent killed (or crashed, or rebooted with its host) while its arm is stopped must bring the
arm back stopped: the stop is an operator's decision, released only by a reset. So every latch
is written to ``<state dir>/<fleet>/<arm>.stop.json`` (the StopRequest, written to a temporary
file, synced and renamed: never half written), and removed by a reset. At start-up the agent
latches every arm that has a file *before* it serves any command; the stop's action is written
as soon as the arm's feedback is fresh. A file that cannot be read still latches its arm (fail
safe), with a reason that says so.

The state directory: ``--state-dir``, else ``$D1_FLEET_STATE_DIR``, else
``$XDG_STATE_HOME/d1-fleet`` (``~/.local/state/d1-fleet``).
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

from fleet.wire import messages as m
from fleet.wire import payloads

log = logging.getLogger("edge_agent.latches")

STATE_ENV = "D1_FLEET_STATE_DIR"


def default_state_dir() -> Path:
    """Where agents keep their latched stops unless told otherwise."""
    given = os.environ.get(STATE_ENV)
    if given:
        return Path(given)
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "d1-fleet"


class LatchStore:
    """The latched stops of one fleet's arms on disk."""

    def __init__(self, directory: Path, fleet: str) -> None:
        self.directory = directory / fleet
        self.directory.mkdir(parents=True, exist_ok=True)

    def _path(self, arm: str) -> Path:
        return self.directory / f"{arm}.stop.json"

    def load(self, arm: str) -> m.StopRequest | None:
        """The stop latched on ``arm`` when its agent last ran, if any."""
        path = self._path(arm)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            return self._unreadable(arm, str(exc))
        try:
            return payloads.STOP.decode(data)
        except payloads.PayloadError as exc:
            return self._unreadable(arm, exc.why[:200])

    @staticmethod
    def _unreadable(arm: str, why: str) -> m.StopRequest:
        log.error("arm %s: its latched stop file is unreadable (%s): latched anyway", arm, why)
        return m.StopRequest(
            stamp_ns=time.time_ns(),
            source="edge-agent",
            stop_id=f"unreadable-latch-{arm}-{time.time_ns()}",
            reason=f"latched before a restart; the latch file was unreadable ({why})",
        )

    def save(self, arm: str, request: m.StopRequest) -> None:
        """Remember that ``request`` is latched on ``arm`` (atomic, synced)."""
        path = self._path(arm)
        temporary = path.with_suffix(".tmp")
        try:
            with open(temporary, "wb") as out:
                out.write(m.encode(request))
                out.flush()
                os.fsync(out.fileno())
            os.replace(temporary, path)
        except OSError as exc:
            log.error("arm %s: could not persist its latched stop (%s)", arm, exc)

    def clear(self, arm: str) -> None:
        """``arm`` was reset."""
        try:
            self._path(arm).unlink()
        except FileNotFoundError:
            return
        except OSError as exc:
            log.error("arm %s: could not remove its latched stop file (%s)", arm, exc)
