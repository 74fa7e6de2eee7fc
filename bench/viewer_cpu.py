"""Section 5 (viewer): the viewer's CPU at several fleet sizes, reusing ``bench/viewer_load.py``
(router, synthetic 10 Hz traffic on the key space and ``fleet viewer`` as separate processes,
no browser attached)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from bench import viewer_load


def run(quick: bool) -> dict[str, Any]:
    """Viewer CPU (% of a core) at 10, 50 and 200 arms."""
    window_s = 5.0 if quick else 10.0
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="d1-bench-viewer-") as tmp:
        for arms in (10, 50, 200):
            result = viewer_load.measure(arms, window_s, browser=False, workdir=Path(tmp))
            out[str(arms)] = result["viewer_cpu_percent_of_a_core"]
    return out
