"""The arm panel as viser renders it, on a real viser server on loopback."""

from __future__ import annotations

import numpy as np


def test_the_arm_panel_renders_bold_readouts_a_seconds_axis_and_unwrapped_cells() -> None:
    """Issue 15's rendering bugs: ``** 29.1**`` shown literally, the plot's x axis as a date,
    the age cell wrapping."""
    import viser

    from testkit.harness import free_port
    from viewer.arm_panel import ArmControls, ArmPanel
    from viewer.panels import fleet_row

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        none = ArmControls(stop=False, reset=False, jog=False)
        panel = ArmPanel(server.gui, "a1", None, True, none, print, print)  # type: ignore[arg-type]
        panel.show(np.array([29.1, -5.0, 0.0, 0.0, 0.0, 0.0, 12.0]))
        assert "j0: **29.1**°" in panel.readout.content
        assert "** " not in panel.readout.content and " **°" not in panel.readout.content
        assert panel.plot.scales == {"x": {"time": False}}
    finally:
        server.stop()
    row = fleet_row("a1", None, True, "0.4 s")
    assert row.count("white-space:nowrap") == 10
