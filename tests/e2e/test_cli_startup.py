"""What a process that never speaks DDS loads: the ``fleet`` command line (every sub-command's
parser), the router and the coordinator start without the CycloneDDS binding, whose import
alone is about 0.15 s of CPU (a third of a router's start). Every test of the suite starts
routers and CLI commands by the hundred, and an operator's ``fleet status`` waits for it."""

from __future__ import annotations

import subprocess
import sys

import pytest

NO_DDS = ("fleet.cli.main", "fleet.coordinator.service", "fleet.client", "fleet.cli.processes")


@pytest.mark.parametrize("module", NO_DDS)
def test_a_process_that_never_speaks_dds_never_loads_it(module: str) -> None:
    probe = (
        f"import sys, {module}; print(sorted(m for m in sys.modules if m.startswith('cyclonedds')))"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", f"{module} loads {done.stdout.strip()}"
