"""The GUI panels: STOP ALL, reset (confirmed), "Fit view", the fleet table, the event log, the
legend, one folder per arm (viewer/arm_panel.py) and one per device in the Devices folder
(viewer/device_panel.py); in a replay, the timeline instead of every command control
(viewer/replay_panel.py).

``update(snapshot)`` runs on the viewer thread at the panel rate and only sends what changed.
GUI callbacks run on viser's threads: they call ``Commander`` methods, which return at once.

A read-only viewer (``commander.read_only``) shows STOP ALL and each arm's and device's stop, the
tables and the readouts, and builds no reset button, no sliders and no device controls; the
commander refuses resets, jogs and device commands anyway. A reset (fleet or one arm) needs both
steps on the server (viewer/confirm.py), not only the browser's dialog. A replay (no commander)
builds no command control at all. The share button (a public tunnel) is hidden; viewer/server.py
refuses the request behind it."""

from __future__ import annotations

import html
import logging
import time
from collections.abc import Callable, Mapping

import numpy as np
import viser

from fleet.d1.limits import JOINT_COUNT
from fleet.web.refusals import Refusals
from fleet.wire import messages as m
from viewer.arm_panel import (
    PLOT_RATE_HZ,
    PLOT_WINDOW_S,
    ArmControls,
    ArmPanel,
    age_text,
    arm_info_html,
)
from viewer.commands import Commander
from viewer.confirm import FLEET, Confirmations
from viewer.dance import dance_html
from viewer.device_panel import DevicePanel
from viewer.events import EventLog
from viewer.replay import ReplayTimeline
from viewer.replay_panel import ReplayControls
from viewer.scene import legend_html
from viewer.state import Snapshot

PLOTS_ON_BY_DEFAULT_UP_TO = 10
"""Fleets up to this many arms show every arm's plot at start; larger ones start with plots off
(each can be switched on in its folder): 200 live plots would cost the browser more than the 3D."""
READOUTS_PER_TICK = 12
"""Arm folders refreshed per panel tick (round robin): fleets up to this size refresh every
arm every tick; a 200-arm fleet refreshes each arm's readout about every 4 s."""


CELL = "padding:0 3px;white-space:nowrap"
"""A table cell: narrow padding (the fleet table fits the panel at 1024 px), never wrapped."""
STICKY = "position:sticky;left:0;z-index:1;"
"""The arm / device id column stays in view while the table scrolls sideways."""
BODY = "var(--mantine-color-body)"
"""The panel's own background (a sticky cell must hide what scrolls under it)."""
SCROLLS = "max-width:100%;overflow-x:auto;scrollbar-width:thin"


def _cells(texts: list[str], background: str) -> str:
    """A row's ``<td>``s, the first (the id) sticky on ``background``."""
    first = f"<td style='{STICKY}{CELL};background:{background}'>{html.escape(texts[0])}</td>"
    return first + "".join(f"<td style='{CELL}'>{html.escape(t)}</td>" for t in texts[1:])


def _head(names: tuple[str, ...], titles: tuple[str, ...] = ()) -> str:
    """A header row's ``<th>``s (``titles``: tooltips), the first sticky."""
    cells = []
    for k, name in enumerate(names):
        title = f" title='{titles[k]}'" if titles else ""
        sticky = STICKY if k == 0 else ""
        cells.append(
            f"<th{title} style='{sticky}{CELL};text-align:left;background:{BODY}'>{name}</th>"
        )
    return "".join(cells)


def _yes(value: bool | None, yes: str = "yes", no: str = "no") -> str:
    return "?" if value is None else (yes if value else no)


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
        "-" if status is None or status.owner is None else status.owner,
        age,
    ]
    # nowrap: "0.4 s" broke over two lines, and a STOPPED row pushed the age out of view
    colour = "#f3d0d0" if (status is not None and status.estopped) else ""
    colour = "#dddddd" if not online else colour
    tds = _cells(cells, colour or BODY)
    style = f" style='background:{colour}'" if colour else ""
    online_attr = "yes" if online else "no"
    return f"<tr data-arm='{html.escape(arm)}' data-online='{online_attr}'{style}>{tds}</tr>"


def devices_html(snapshot: Snapshot) -> str:
    """The devices beside the arms (grippers, G1s): one ``<tr data-device>`` each, with the
    kind's own one-line summary (``fleet status``'s)."""
    rows = []
    for view in snapshot.devices:
        state = view.state
        stopped = state is not None and bool(getattr(state, "estopped", False))
        link = "-" if state is None else str(getattr(state, "link", "?"))
        cells = [
            view.device,
            view.kind,
            view.mount or "-",
            link,
            "STOPPED" if stopped else "no",
            age_text(view.age_s),
        ]
        summary = view.summary
        tds = _cells(cells, "#f3d0d0" if stopped else BODY)
        # The kind's summary on a line of its own under the row: squeezed into a column
        # beside six others it wrapped to 4-5 lines.
        line = f"<td colspan='{len(cells)}' style='padding:0 3px 2px 12px'>"
        line += f"{html.escape(summary)}</td>"
        style = " style='background:#f3d0d0'" if stopped else ""
        rows.append(
            f"<tbody data-device='{html.escape(view.device)}'{style}><tr>{tds}</tr>"
            f"<tr data-field='state'>{line}</tr></tbody>"
        )
    head = _head(("device", "kind", "on", "link", "stop", "age"))
    return (
        f"<div style='{SCROLLS}'><table id='device-table' style='font-size:0.8em'>"
        f"<tr>{head}</tr>{''.join(rows)}</table></div>"
    )


class FleetTable:
    """The fleet panel's HTML table; rows are rebuilt only when their inputs changed."""

    COLUMNS = (
        ("arm", "arm"),
        ("agent", "agent"),
        ("link", "link"),
        ("en", "enabled"),
        ("pwr", "powered"),
        ("err", "error"),
        ("stop", "stop"),
        ("contact", "contact"),
        ("owner", "owner"),
        ("age", "age"),
    )
    """(header, its meaning as a tooltip): short headers, so the table fits the panel."""
    HEAD = _head(tuple(h for h, _ in COLUMNS), tuple(title for _, title in COLUMNS))

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
        return f"<div style='{SCROLLS}'>{table}</div>{why}"  # scrolls rather than clips


class FleetPanels:
    """Every GUI element of the viewer (shared by all browsers). ``commander`` None: a replay
    (``timeline`` drives it); ``fit(client)`` frames the fleet in that browser; ``devices``:
    device id -> its kind's key, the devices beside the arms (a "Devices" table and folder
    each)."""

    def __init__(
        self,
        server: viser.ViserServer,
        arms: tuple[str, ...],
        commander: Commander | None,
        events: EventLog,
        fit: Callable[[viser.ClientHandle], None] | None = None,
        timeline: ReplayTimeline | None = None,
        devices: Mapping[str, str] | None = None,
    ) -> None:
        self.server = server
        self.commander = commander
        self.arms = arms
        self.events = events
        self.read_only = commander is None or commander.read_only
        self.confirmations = Confirmations()
        self.refusals = Refusals(logging.getLogger("viewer.panels"))
        gui = server.gui
        # The share button would ask for a public tunnel to the viewer: never shown.
        gui.configure_theme(control_width="large", show_share_button=False)
        self.stop_button: viser.GuiButtonHandle | None = None
        self.reset_button: viser.GuiButtonHandle | None = None
        self.replay = None if timeline is None else ReplayControls(gui, timeline)
        if commander is not None:
            self.stop_button = gui.add_button(
                "STOP ALL",
                color="red",
                icon=viser.Icon.HAND_STOP,
                hint="protective stop, every arm and device",
            )
            self.stop_button.on_click(lambda _e: self._on_stop(None))
            if self.read_only:
                gui.add_markdown(
                    f"Read-only viewer (principal `{commander.principal}`): stop only. "
                    "`fleet viewer --principal operator` gives reset and jog."
                )
            else:
                self.reset_button = gui.add_button("Reset stop…", color="gray")
                self.reset_button.on_click(lambda e: self._on_reset(e, None))
        self.fit_button = gui.add_button(
            "Fit view", icon=viser.Icon.FOCUS_2, hint="frame every arm"
        )
        self.fit_button.on_click(lambda e: fit(e.client) if fit and e.client else None)
        self.stop_info = gui.add_markdown("")
        # The dances' status, above the tables: a stopped dance says so, and why, in red.
        self.dance_status = gui.add_html(dance_html(()))
        self.dance_text = ""
        self.table_html = ""
        self.events_version = -1
        self.fleet_table = FleetTable()
        self._next_readout = 0
        with gui.add_folder("Fleet"):
            self.table = gui.add_html("")
        self.devices_table = None
        self.devices_text = ""
        self.device_panels: dict[str, DevicePanel] = {}
        controls = ArmControls.for_viewer(commander)
        if devices:
            with gui.add_folder("Devices"):
                self.devices_table = gui.add_html("")
                for device, kind in devices.items():
                    self.device_panels[device] = DevicePanel(
                        gui, device, kind, commander, controls, self._on_stop, self._on_reset
                    )
        with gui.add_folder("Events"):
            self.event_log = gui.add_html(events.html())
        with gui.add_folder("Legend", expand_by_default=False):
            gui.add_html(legend_html())
        plot_on = len(self.arms) <= PLOTS_ON_BY_DEFAULT_UP_TO
        self.arm_panels = [
            ArmPanel(gui, arm, commander, plot_on, controls, self._on_stop, self._on_reset)
            for arm in self.arms
        ]
        n = int(PLOT_WINDOW_S * PLOT_RATE_HZ)
        self._history = np.zeros((len(self.arms), n, JOINT_COUNT))
        self._history_t = np.linspace(-PLOT_WINDOW_S, 0.0, n)
        self._next_sample = 0.0

    def _on_stop(self, arm: str | None) -> None:
        if self.commander is None:
            return
        request = self.commander.stop(arm)
        what = "STOP ALL" if arm is None else f"stop {arm}"
        self.stop_info.content = f"{what} sent at {time.strftime('%H:%M:%S')} ({request.stop_id})"

    def _on_reset(self, event: viser.GuiEvent, arm: str | None) -> None:
        client = event.client
        if client is None or self.read_only:
            return
        target = FLEET if arm is None else arm
        nonce = self.confirmations.request(client.client_id, target)
        title = "Reset the fleet's stop?" if arm is None else f"Reset the stop of {arm}?"
        whose = "of **every** arm and device" if arm is None else f"of **{arm}** only"
        if arm is not None and arm not in self.device_panels:
            whose += " (and of what is mounted on it)"
        with client.gui.add_modal(title) as modal:
            client.gui.add_markdown(
                f"Releases the latched stop {whose}. It does not move anything: each arm holds "
                "its measured pose and each device stays where it is until someone commands it "
                "(the demo's dance does not start again by itself). Check the cell is clear "
                "first."
            )
            confirm = client.gui.add_button(
                "Reset every arm and device" if arm is None else f"Reset {arm}", color="red"
            )
            cancel = client.gui.add_button("Cancel")

            def do_reset(e: viser.GuiEvent) -> None:
                modal.close()
                # The client that clicked, not the one the dialog was made for: they must match.
                if not self.confirm_reset(
                    -1 if e.client is None else e.client.client_id, nonce, arm
                ):
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

    def confirm_reset(self, client_id: int, nonce: str, arm: str | None = None) -> bool:
        """Step two of a reset of ``arm`` (None: the fleet): sends it only if ``client_id``
        asked about that very target (step one, ``nonce``) within the confirmation window and
        the viewer may reset."""
        target = FLEET if arm is None else arm
        if self.commander is None or not self.confirmations.confirm(client_id, nonce, target):
            self.refusals.refuse(
                "reset", f"a reset confirmation from client {client_id} with no pending request"
            )
            return False
        if not self.commander.reset(arm):
            return False
        what = "reset" if arm is None else f"reset of {arm}"
        self.stop_info.content = f"{what} sent at {time.strftime('%H:%M:%S')}"
        return True

    def record(self, snapshot: Snapshot, now: float) -> None:
        """Add a plot sample (at most PLOT_RATE_HZ; cheap: one array roll for all arms)."""
        if now < self._next_sample:
            return
        self._next_sample = now + 1.0 / PLOT_RATE_HZ
        self._history = np.roll(self._history, -1, axis=1)
        self._history[:, -1] = snapshot.angles_deg

    def update(self, snapshot: Snapshot) -> None:
        """Refresh the table, the event log, readouts, plots and slider states (only what
        changed)."""
        dance = dance_html(snapshot.dances)
        if dance != self.dance_text:
            self.dance_text = dance
            self.dance_status.content = dance
        table = self.fleet_table.html(snapshot)
        if table != self.table_html:
            self.table_html = table
            self.table.content = table
        if self.devices_table is not None:
            text = devices_html(snapshot)
            if text != self.devices_text:
                self.devices_text = text
                self.devices_table.content = text
            for view in snapshot.devices:
                panel = self.device_panels.get(view.device)
                if panel is not None:
                    panel.update(view)
        if self.events.version != self.events_version:
            self.events_version = self.events.version
            self.event_log.content = self.events.html()
        if self.replay is not None:
            with self.server.atomic():  # its button's label and icon change together
                self.replay.update()
        has = np.isfinite(snapshot.joints_age_s)
        blocked = snapshot.estopped | ~snapshot.online | snapshot.stale
        for i, panel in enumerate(self.arm_panels):
            panel.set_blocked(bool(blocked[i]))
        contact = snapshot.contact_rows()
        # Readouts and plots: at most READOUTS_PER_TICK arms per tick, round robin, so a large
        # fleet costs the same per tick as a small one (each arm refreshes less often).
        count = min(READOUTS_PER_TICK, len(self.arm_panels))
        for k in range(count):
            i = (self._next_readout + k) % len(self.arm_panels)
            panel = self.arm_panels[i]
            in_contact = tuple(bool(c) for c in contact[i])
            panel.show_info(
                arm_info_html(
                    panel.arm,
                    snapshot.status[i],
                    snapshot.diag_of(i),
                    bool(snapshot.online[i]),
                    float(snapshot.joints_age_s[i]),
                    in_contact,
                )
            )
            if has[i]:
                panel.show(snapshot.angles_deg[i], in_contact)
                if panel.show_plot.value:
                    panel.plot.data = (self._history_t, *self._history[i].T.copy())
        self._next_readout = (self._next_readout + count) % max(1, len(self.arm_panels))

    def notify(self, title: str, body: str, is_error: bool) -> None:
        """A notification in every connected browser (callable from any thread)."""
        for client in self.server.get_clients().values():
            client.add_notification(
                title, body, color="red" if is_error else "blue", auto_close_seconds=8.0
            )
