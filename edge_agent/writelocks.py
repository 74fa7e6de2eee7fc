"""One write lock per robot, the core's: every write to a robot's DDS writers happens under it
(an arm's D1 commands in ``fleet/d1arm/writer.py``, a device driver's commands and stop
actions), so a stop's write and a command's never interleave. Created at start-up, one per
unit; never held across a Zenoh put."""

from __future__ import annotations

import threading


class WriteLocks:
    """The write lock of each unit of the agent."""

    def __init__(self, units: list[str]) -> None:
        self._locks = {unit: threading.Lock() for unit in units}

    def of(self, unit: str) -> threading.Lock:
        """The write lock of ``unit``."""
        return self._locks[unit]
