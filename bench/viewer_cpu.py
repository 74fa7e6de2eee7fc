"""Section 5 (viewer): the viewer's CPU at several fleet sizes, reusing ``bench/viewer_load.py``
(router, synthetic 10 Hz traffic on the key space and ``fleet viewer`` as separate processes,
no browser attached); and at 50 arms with a G1 drawn too (its lowstate, arms swinging, and its
state at the G1 config's ``relay_hz``, as its agent relays them)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

from bench import viewer_load

G1_ID = "h1"
G1_KEY = "50+g1"
"""The G1 run's entry in the section's results (beside the arm counts)."""


def run(quick: bool) -> dict[str, Any]:
    """Viewer CPU (% of a core) at 10, 50 and 200 arms; at 50 arms and a G1 (a dict: its
    figure, the G1's relay rate)."""
    window_s = 5.0 if quick else 10.0
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="d1-bench-viewer-") as tmp:
        for arms in (10, 50, 200):
            result = viewer_load.measure(arms, window_s, browser=False, workdir=Path(tmp))
            out[str(arms)] = result["viewer_cpu_percent_of_a_core"]
            if arms == 50:
                g1 = viewer_load.measure(50, window_s, False, Path(tmp), g1s=(G1_ID,))
                out[G1_KEY] = {
                    "arms": 50,
                    "g1s": 1,
                    "g1_relay_hz": g1["g1_relay_hz"][G1_ID],
                    "viewer_cpu_percent_of_a_core": g1["viewer_cpu_percent_of_a_core"],
                }
    return out
