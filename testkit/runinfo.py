"""Where and when a measurement ran, for the header of a results table: the machine (host
name, CPUs, Python), the load average and the date. Shared by ``make bench``, the contact
benchmark and the network lab's row records, so every results page names its run alike."""

from __future__ import annotations

import datetime
import os
import platform
from pathlib import Path


def machine() -> str:
    """``host, N x CPU model, Python x.y.z``."""
    return f"{host()}, {cpus()}, Python {platform.python_version()}"


def host() -> str:
    """This machine's host name."""
    return platform.node()


def cpus() -> str:
    """``N x CPU model``."""
    return f"{os.cpu_count()} x {cpu_model()}"


def cpu_model() -> str:
    """The first CPU's model name (``unknown CPU`` where /proc/cpuinfo does not say)."""
    try:
        lines = Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines()
    except OSError:
        return "unknown CPU"
    for line in lines:
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown CPU"


def load() -> tuple[float, float, float]:
    """The load average over 1, 5 and 15 minutes."""
    one, five, fifteen = os.getloadavg()
    return round(one, 2), round(five, 2), round(fifteen, 2)


def now_iso() -> str:
    """The local time with its offset, to the second (``2026-11-26T09:55:06+00:00``)."""
    return datetime.datetime.now().astimezone().isoformat(timespec="seconds")
