"""The GUI panels: STOP ALL, reset (confirmed), the fleet table, and one folder per arm with
live joint readouts, a plot of the last seconds and jog sliders.

``update(snapshot)`` runs on the viewer thread at the panel rate and only sends what changed.
GUI callbacks run on viser's threads: they call ``Commander`` methods, which return at once.
"""

from __future__ import annotations

import html
import time

import numpy as np
import numpy.typing as npt
import viser

from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG
from fleet.inventory import Inventory
from fleet.wire import messages as m
from viewer.commands import Commander
from viewer.state import Snapshot

PLOT_WINDOW_S = 10.0
PLOT_RATE_HZ = 10.0
PLOTS_ON_BY_DEFAULT_UP_TO = 10
"""Fleets up to this many arms show every arm's plot at start; larger ones start with plots off
(each can be switched on in its folder): 200 live plots would cost the browser more than the 3D."""
JOINT_COLOURS = ("#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#008080", "#9a6324")


def _yes(value: bool | None, yes: str = "yes", no: str = "no") -> str:
    return "?" if value is None else (yes if value else no)


def fleet_row(arm: str, status: m.ArmStatus | None, online: bool, age_s: float) -> str:
    """One ``<tr>`` of the fleet table (``data-arm``/``data-online`` for scripts and tests)."""
    age = "-" if not np.isfinite(age_s) else f"{age_s:.1f} s"
    cells = [
        arm,
        "online" if online else "OFFLINE",
        "-" if status is None else status.link,
        _yes(None if status is None else status.enabled),
        _yes(None if status is None else status.powered),
        _yes(None if status is None else status.error, "ERROR", "no"),
        "STOPPED" if status is not None and status.estopped else "no",
        age,
    ]
    tds = "".join(f"<td style='padding:0 6px'>{html.escape(c)}</td>" for c in cells)
    colour = "#f3d0d0" if (status is not None and status.estopped) else ""
    colour = "#dddddd" if not online else colour
    style = f" style='background:{colour}'" if colour else ""
    online_attr = "yes" if online else "no"
    return f"<tr data-arm='{html.escape(arm)}' data-online='{online_attr}'{style}>{tds}</tr>"


def fleet_table(snapshot: Snapshot) -> str:
    """The fleet panel's HTML table."""
    head = "".join(
        f"<th style='padding:0 6px;text-align:left'>{h}</th>"
        for h in ("arm", "agent", "link", "enabled", "powered", "error", "stop", "age")
    )
    rows = "".join(
        fleet_row(arm, snapshot.status[i], bool(snapshot.online[i]), snapshot.joints_age_s[i])
        for i, arm in enumerate(snapshot.arms)
    )
    return f"<table id='fleet-table' style='font-size:0.8em'><tr>{head}</tr>{rows}</table>"


class _ArmPanel:
    """The folder of one arm."""

    def __init__(self, gui: viser.GuiApi, arm: str, commander: Commander, plot_on: bool) -> None:
        self.arm = arm
        self.synced = False
        self.blocked: bool | None = None
        self.readout_text = ""
        with gui.add_folder(f"Arm {arm}", expand_by_default=False):
            self.readout = gui.add_markdown("no feedback yet")
            self.show_plot = gui.add_checkbox("plot", initial_value=plot_on)
            n = int(PLOT_WINDOW_S * PLOT_RATE_HZ)
            self.plot = gui.add_uplot(
                data=(np.linspace(-PLOT_WINDOW_S, 0.0, n), *(np.zeros(n),) * JOINT_COUNT),
                series=(
                    {"label": "t (s)"},
                    *(
                        {"label": f"j{j}", "stroke": JOINT_COLOURS[j], "width": 1}
                        for j in range(JOINT_COUNT)
                    ),
                ),
                title=f"{arm} joints (deg)",
                aspect=1.6,
                visible=plot_on,
            )
            self.show_plot.on_update(lambda _e: setattr(self.plot, "visible", self.show_plot.value))
            self.sliders = []
            for joint, (low, high) in enumerate(JOINT_RANGE_DEG):
                slider = gui.add_slider(
                    f"jog j{joint}", min=low, max=high, step=0.5, initial_value=0.0, disabled=True
                )
                slider.on_update(self._on_slide(commander, joint))
                self.sliders.append(slider)
            self.sync = gui.add_button("sliders to measured", hint="set the sliders to the arm")
            self.sync.on_click(lambda _e: setattr(self, "synced", False))

    def _on_slide(self, commander: Commander, joint: int):  # type: ignore[no-untyped-def]
        def on_update(event: viser.GuiEvent) -> None:
            if event.client is None or self.blocked:
                return  # our own sync from feedback, or a stale click on a disabled arm
            commander.jog(self.arm, joint, float(event.target.value))

        return on_update

    def update(self, angles: npt.NDArray[np.float64], has_joints: bool, blocked: bool) -> None:
        if blocked != self.blocked:
            self.blocked = blocked
            for slider in self.sliders:
                slider.disabled = blocked
        if not has_joints:
            return
        text = "  \n".join(
            f"j{j}: **{a:7.1f}**°" for j, a in enumerate(np.round(angles, 1).tolist())
        )
        if text != self.readout_text:
            self.readout_text = text
            self.readout.content = text
        if not self.synced:
            self.synced = True
            for slider, angle in zip(self.sliders, angles.tolist(), strict=True):
                slider.value = float(np.clip(round(angle * 2) / 2, slider.min, slider.max))


class FleetPanels:
    """Every GUI element of the viewer (shared by all browsers)."""

    def __init__(self, server: viser.ViserServer, inventory: Inventory, commander: Commander):
        self.server = server
        self.commander = commander
        self.arms = tuple(inventory.arms)
        gui = server.gui
        gui.configure_theme(control_width="large")
        self.stop_button = gui.add_button(
            "STOP ALL", color="red", icon=viser.Icon.HAND_STOP, hint="protective stop, every arm"
        )
        self.stop_button.on_click(lambda _e: self._on_stop())
        self.reset_button = gui.add_button("Reset stop…", color="gray")
        self.reset_button.on_click(self._on_reset)
        self.stop_info = gui.add_markdown("")
        self.table_html = ""
        with gui.add_folder("Fleet"):
            self.table = gui.add_html("")
        plot_on = len(self.arms) <= PLOTS_ON_BY_DEFAULT_UP_TO
        self.arm_panels = [_ArmPanel(gui, arm, commander, plot_on) for arm in self.arms]
        n = int(PLOT_WINDOW_S * PLOT_RATE_HZ)
        self._history = np.zeros((len(self.arms), n, JOINT_COUNT))
        self._history_t = np.linspace(-PLOT_WINDOW_S, 0.0, n)
        self._next_sample = 0.0

    def _on_stop(self) -> None:
        request = self.commander.stop_all()
        self.stop_info.content = f"STOP ALL sent at {time.strftime('%H:%M:%S')} ({request.stop_id})"

    def _on_reset(self, event: viser.GuiEvent) -> None:
        client = event.client
        if client is None:
            return
        with client.gui.add_modal("Reset the fleet's stop?") as modal:
            client.gui.add_markdown(
                "Releases the latched stop of **every** arm. Arms do not move: each holds its "
                "measured pose. Check the cell is clear first."
            )
            confirm = client.gui.add_button("Reset every arm", color="red")
            cancel = client.gui.add_button("Cancel")

            def do_reset(_e: viser.GuiEvent) -> None:
                modal.close()
                self.commander.reset_all()
                self.stop_info.content = f"reset sent at {time.strftime('%H:%M:%S')}"

            confirm.on_click(do_reset)
            cancel.on_click(lambda _e: modal.close())

    def record(self, snapshot: Snapshot, now: float) -> None:
        """Add a plot sample (at most PLOT_RATE_HZ; cheap: one array roll for all arms)."""
        if now < self._next_sample:
            return
        self._next_sample = now + 1.0 / PLOT_RATE_HZ
        self._history = np.roll(self._history, -1, axis=1)
        self._history[:, -1] = snapshot.angles_deg

    def update(self, snapshot: Snapshot) -> None:
        """Refresh the table, readouts, plots and slider states (only what changed)."""
        table = fleet_table(snapshot)
        if table != self.table_html:
            self.table_html = table
            self.table.content = table
        estopped, has = snapshot.estopped, np.isfinite(snapshot.joints_age_s)
        for i, panel in enumerate(self.arm_panels):
            blocked = bool(estopped[i] or not snapshot.online[i] or snapshot.stale[i])
            panel.update(snapshot.angles_deg[i], bool(has[i]), blocked)
            if panel.show_plot.value and has[i]:
                panel.plot.data = (self._history_t, *self._history[i].T.copy())

    def notify(self, title: str, body: str, is_error: bool) -> None:
        """A notification in every connected browser (callable from any thread)."""
        for client in self.server.get_clients().values():
            client.add_notification(
                title, body, color="red" if is_error else "blue", auto_close_seconds=8.0
            )
