"""The GUI panels: STOP ALL, reset (confirmed), the fleet table, and one folder per arm with
live joint readouts, a plot of the last seconds and jog sliders.

``update(snapshot)`` runs on the viewer thread at the panel rate and only sends what changed.
GUI callbacks run on viser's threads: they call ``Commander`` methods, which return at once.

A read-only viewer (``commander.read_only``) shows STOP ALL, the table and the readouts, and
builds no reset button and no sliders; the commander refuses resets and jogs anyway. The reset
needs both steps on the server (viewer/confirm.py), not only the browser's dialog. The share
button (a public tunnel) is hidden; viewer/server.py refuses the request behind it.
"""

from __future__ import annotations

import html
import logging
import time

import numpy as np
import numpy.typing as npt
import viser

from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG, JointRanges
from fleet.inventory import Inventory
from fleet.wire import messages as m
from viewer.commands import JOG_INTERVAL_S, MAX_JOG_STEP_DEG, Commander
from viewer.confirm import Confirmations
from viewer.refusals import Refusals
from viewer.scene import legend_html
from viewer.state import Snapshot

PLOT_WINDOW_S = 10.0
PLOT_RATE_HZ = 10.0
PLOTS_ON_BY_DEFAULT_UP_TO = 10
"""Fleets up to this many arms show every arm's plot at start; larger ones start with plots off
(each can be switched on in its folder): 200 live plots would cost the browser more than the 3D."""
READOUTS_PER_TICK = 12
"""Arm folders refreshed per panel tick (round robin): fleets up to this size refresh every
arm every tick; a 200-arm fleet refreshes each arm's readout about every 4 s."""
JOINT_COLOURS = ("#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#008080", "#9a6324")


SLIDER_HOLD_S = 1.5
"""After the operator touched a slider, the sliders stop following the arm this long (so the
slider under the hand does not jump while the arm moves)."""


def _yes(value: bool | None, yes: str = "yes", no: str = "no") -> str:
    return "?" if value is None else (yes if value else no)


def age_text(age_s: float) -> str:
    """Feedback age, coarse enough that the table does not change every tick at 10 Hz."""
    if not np.isfinite(age_s):
        return "-"
    return "< 0.5 s" if age_s < 0.5 else f"{age_s:.0f} s" if age_s >= 10 else f"{age_s:.1f} s"


def contact_text(joints_in_contact: tuple[bool, ...]) -> str:
    """``j2 j3`` for the joints in confirmed contact, ``no`` for none."""
    return " ".join(f"j{j}" for j, on in enumerate(joints_in_contact) if on) or "no"


def fleet_row(
    arm: str, status: m.ArmStatus | None, online: bool, age: str, contact: str = "no"
) -> str:
    """One ``<tr>`` of the fleet table (``data-arm``/``data-online`` for scripts and tests);
    a stopped arm's stop cell carries the stop's reason (shown below the table too)."""
    cells = [
        arm,
        "online" if online else "OFFLINE",
        "-" if status is None else status.link,
        _yes(None if status is None else status.enabled),
        _yes(None if status is None else status.powered),
        _yes(None if status is None else status.error, "ERROR", "no"),
        "STOPPED" if status is not None and status.estopped else "no",
        contact,
        age,
    ]
    # nowrap: "0.4 s" broke over two lines, and a STOPPED row pushed the age out of view
    tds = "".join(
        f"<td style='padding:0 6px;white-space:nowrap'>{html.escape(c)}</td>" for c in cells
    )
    colour = "#f3d0d0" if (status is not None and status.estopped) else ""
    colour = "#dddddd" if not online else colour
    style = f" style='background:{colour}'" if colour else ""
    online_attr = "yes" if online else "no"
    return f"<tr data-arm='{html.escape(arm)}' data-online='{online_attr}'{style}>{tds}</tr>"


class FleetTable:
    """The fleet panel's HTML table; rows are rebuilt only when their inputs changed."""

    HEAD = "".join(
        f"<th style='padding:0 6px;text-align:left'>{h}</th>"
        for h in ("arm", "agent", "link", "enabled", "powered", "error", "stop", "contact", "age")
    )

    def __init__(self) -> None:
        self._rows: dict[str, tuple[object, str]] = {}

    def html(self, snapshot: Snapshot) -> str:
        """The whole table for ``snapshot``."""
        rows = []
        reasons = []
        contact = snapshot.contact_rows()
        for i, arm in enumerate(snapshot.arms):
            status = snapshot.status[i]
            key = (
                status,
                bool(snapshot.online[i]),
                age_text(snapshot.joints_age_s[i]),
                contact_text(tuple(bool(c) for c in contact[i])),
            )
            cached = self._rows.get(arm)
            if cached is None or cached[0] != key:
                cached = (key, fleet_row(arm, key[0], key[1], key[2], key[3]))
                self._rows[arm] = cached
            rows.append(cached[1])
            if status is not None and status.estopped and status.stop_reason:
                reasons.append(f"<div>{html.escape(arm)}: {html.escape(status.stop_reason)}</div>")
        body = "".join(rows)
        head = f"<tr>{self.HEAD}</tr>"
        table = f"<table id='fleet-table' style='font-size:0.8em'>{head}{body}</table>"
        why = f"<div id='stop-reasons' style='font-size:0.8em'>{''.join(reasons)}</div>"
        return f"<div style='overflow-x:auto'>{table}</div>{why}"  # scrolls rather than clips


class _ArmPanel:
    """The folder of one arm."""

    def __init__(
        self,
        gui: viser.GuiApi,
        arm: str,
        commander: Commander,
        plot_on: bool,
        jog: bool,
        ranges: JointRanges = JOINT_RANGE_DEG,
    ) -> None:
        self.arm = arm
        self.blocked: bool | None = None
        self.measured: npt.NDArray[np.float64] | None = None
        self.jogged_s = -SLIDER_HOLD_S
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
                # uPlot reads x as a Unix time unless told: -10..0 s read "12/31/69 11:59pm".
                scales={"x": {"time": False}},
                aspect=1.6,
                visible=plot_on,
            )
            self.show_plot.on_update(lambda _e: setattr(self.plot, "visible", self.show_plot.value))
            self.sliders = []
            if not jog:
                return  # read-only: no sliders at all (the commander would refuse them anyway)
            for joint, (low, high) in enumerate(ranges):  # the arm's: its gripper's own
                slider = gui.add_slider(
                    f"jog j{joint}", min=low, max=high, step=0.5, initial_value=0.0, disabled=True
                )
                slider.on_update(self._on_slide(commander, joint))
                self.sliders.append(slider)
            gui.add_markdown(
                f"Jog: each move goes at most {MAX_JOG_STEP_DEG:g}° from the measured angle, "
                f"one every {JOG_INTERVAL_S:g} s, and takes the arm's lease (a script holding "
                "it refuses the jog, naming itself). The sliders follow the arm."
            )

    def _on_slide(self, commander: Commander, joint: int):  # type: ignore[no-untyped-def]
        def on_update(event: viser.GuiEvent) -> None:
            if event.client is None or self.blocked or self.measured is None:
                return  # our own sync from feedback, a stale click, or nothing measured yet
            self.jogged_s = time.monotonic()
            measured = float(self.measured[joint])
            commander.jog(self.arm, joint, float(event.target.value), measured)

        return on_update

    def set_blocked(self, blocked: bool) -> None:
        """Disable the jog sliders while the arm is stopped, stale or offline."""
        if blocked != self.blocked:
            self.blocked = blocked
            for slider in self.sliders:
                slider.disabled = blocked

    def show(self, angles: npt.NDArray[np.float64]) -> None:
        """Refresh the readout, and the sliders unless the operator is using them, from the
        measured angles: a jog always starts from where the arm is."""
        self.measured = angles.copy()
        text = "  \n".join(
            # No padding inside the markers: "** 29.1**" is not bold in Markdown, it is literal.
            f"j{j}: **{a:.1f}**°"
            for j, a in enumerate(np.round(angles, 1).tolist())
        )
        if text != self.readout_text:
            self.readout_text = text
            self.readout.content = text
        if self.sliders and time.monotonic() - self.jogged_s >= SLIDER_HOLD_S:
            for slider, angle in zip(self.sliders, angles.tolist(), strict=True):
                value = float(np.clip(round(angle * 2) / 2, slider.min, slider.max))
                if value != slider.value:
                    slider.value = value


class FleetPanels:
    """Every GUI element of the viewer (shared by all browsers)."""

    def __init__(self, server: viser.ViserServer, inventory: Inventory, commander: Commander):
        self.server = server
        self.commander = commander
        self.arms = tuple(inventory.arms)
        self.read_only = commander.read_only
        self.confirmations = Confirmations()
        self.refusals = Refusals(logging.getLogger("viewer.panels"))
        gui = server.gui
        # The share button would ask for a public tunnel to the viewer: never shown.
        gui.configure_theme(control_width="large", show_share_button=False)
        self.stop_button = gui.add_button(
            "STOP ALL", color="red", icon=viser.Icon.HAND_STOP, hint="protective stop, every arm"
        )
        self.stop_button.on_click(lambda _e: self._on_stop())
        self.reset_button: viser.GuiButtonHandle | None = None
        if self.read_only:
            gui.add_markdown(
                f"Read-only viewer (principal `{commander.principal}`): STOP ALL only. "
                "`fleet viewer --principal operator` gives reset and jog."
            )
        else:
            self.reset_button = gui.add_button("Reset stop…", color="gray")
            self.reset_button.on_click(self._on_reset)
        self.stop_info = gui.add_markdown("")
        self.table_html = ""
        self.fleet_table = FleetTable()
        self._next_readout = 0
        with gui.add_folder("Fleet"):
            self.table = gui.add_html("")
        with gui.add_folder("Legend", expand_by_default=False):
            gui.add_html(legend_html())
        plot_on = len(self.arms) <= PLOTS_ON_BY_DEFAULT_UP_TO
        self.arm_panels = [
            _ArmPanel(
                gui,
                arm,
                commander,
                plot_on,
                jog=not self.read_only,
                ranges=inventory.arms[arm].joint_ranges_deg,
            )
            for arm in self.arms
        ]
        n = int(PLOT_WINDOW_S * PLOT_RATE_HZ)
        self._history = np.zeros((len(self.arms), n, JOINT_COUNT))
        self._history_t = np.linspace(-PLOT_WINDOW_S, 0.0, n)
        self._next_sample = 0.0

    def _on_stop(self) -> None:
        request = self.commander.stop_all()
        self.stop_info.content = f"STOP ALL sent at {time.strftime('%H:%M:%S')} ({request.stop_id})"

    def _on_reset(self, event: viser.GuiEvent) -> None:
        client = event.client
        if client is None or self.read_only:
            return
        nonce = self.confirmations.request(client.client_id)
        with client.gui.add_modal("Reset the fleet's stop?") as modal:
            client.gui.add_markdown(
                "Releases the latched stop of **every** arm. Arms do not move: each holds its "
                "measured pose. Check the cell is clear first."
            )
            confirm = client.gui.add_button("Reset every arm", color="red")
            cancel = client.gui.add_button("Cancel")

            def do_reset(e: viser.GuiEvent) -> None:
                modal.close()
                # The client that clicked, not the one the dialog was made for: they must match.
                if not self.confirm_reset(-1 if e.client is None else e.client.client_id, nonce):
                    client.add_notification(
                        "Reset not sent",
                        "the confirmation expired or was already used: press Reset again",
                        color="red",
                        auto_close_seconds=8.0,
                    )

            def do_cancel(_e: viser.GuiEvent) -> None:
                modal.close()
                self.confirmations.cancel(client.client_id)

            confirm.on_click(do_reset)
            cancel.on_click(do_cancel)

    def confirm_reset(self, client_id: int, nonce: str) -> bool:
        """Step two of the reset: sends it only if ``client_id`` asked (step one, ``nonce``)
        within the confirmation window and the viewer may reset."""
        if not self.confirmations.confirm(client_id, nonce):
            self.refusals.refuse(
                "reset", f"a reset confirmation from client {client_id} with no pending request"
            )
            return False
        if not self.commander.reset_all():
            return False
        self.stop_info.content = f"reset sent at {time.strftime('%H:%M:%S')}"
        return True

    def record(self, snapshot: Snapshot, now: float) -> None:
        """Add a plot sample (at most PLOT_RATE_HZ; cheap: one array roll for all arms)."""
        if now < self._next_sample:
            return
        self._next_sample = now + 1.0 / PLOT_RATE_HZ
        self._history = np.roll(self._history, -1, axis=1)
        self._history[:, -1] = snapshot.angles_deg

    def update(self, snapshot: Snapshot) -> None:
        """Refresh the table, readouts, plots and slider states (only what changed)."""
        table = self.fleet_table.html(snapshot)
        if table != self.table_html:
            self.table_html = table
            self.table.content = table
        has = np.isfinite(snapshot.joints_age_s)
        blocked = snapshot.estopped | ~snapshot.online | snapshot.stale
        for i, panel in enumerate(self.arm_panels):
            panel.set_blocked(bool(blocked[i]))
        # Readouts and plots: at most READOUTS_PER_TICK arms per tick, round robin, so a large
        # fleet costs the same per tick as a small one (each arm refreshes less often).
        count = min(READOUTS_PER_TICK, len(self.arm_panels))
        for k in range(count):
            i = (self._next_readout + k) % len(self.arm_panels)
            panel = self.arm_panels[i]
            if has[i]:
                panel.show(snapshot.angles_deg[i])
                if panel.show_plot.value:
                    panel.plot.data = (self._history_t, *self._history[i].T.copy())
        self._next_readout = (self._next_readout + count) % max(1, len(self.arm_panels))

    def notify(self, title: str, body: str, is_error: bool) -> None:
        """A notification in every connected browser (callable from any thread)."""
        for client in self.server.get_clients().values():
            client.add_notification(
                title, body, color="red" if is_error else "blue", auto_close_seconds=8.0
            )
