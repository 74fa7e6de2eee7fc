"""One arm's folder in the viewer: who holds it, its stop and contact state, the agent's counters,
live joint readouts, a plot of the last seconds, its own stop and reset, and the jog sliders.

``ArmControls`` says what the folder may offer: a replay offers nothing that commands; a
read-only (observer) viewer offers the arm's stop only; an operator's offers stop, reset (with a
confirmation checked on the server, see viewer/panels.py) and jog.
"""

from __future__ import annotations

import html
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import viser

from fleet.d1.limits import JOINT_COUNT
from fleet.wire import messages as m
from viewer.commands import JOG_INTERVAL_S, MAX_JOG_STEP_DEG, Commander

PLOT_WINDOW_S = 10.0
PLOT_RATE_HZ = 10.0
JOINT_COLOURS = ("#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#008080", "#9a6324")
CONTACT_MARK = "⚠ contact"
SLIDER_HOLD_S = 1.5
"""After the operator touched a slider, the sliders stop following the arm this long (so the
slider under the hand does not jump while the arm moves)."""


@dataclass(frozen=True)
class ArmControls:
    """What an arm's folder offers: ``stop`` (anyone live), ``reset`` and ``jog`` (a viewer
    whose principal may command)."""

    stop: bool
    reset: bool
    jog: bool

    @staticmethod
    def for_viewer(commander: Commander | None) -> ArmControls:
        """None (a replay): nothing; a read-only commander: stop; otherwise all three."""
        if commander is None:
            return ArmControls(False, False, False)
        may = not commander.read_only
        return ArmControls(True, may, may)


def age_text(age_s: float) -> str:
    """Feedback age, coarse enough that the table does not change every tick at 10 Hz."""
    if not np.isfinite(age_s):
        return "-"
    return "< 0.5 s" if age_s < 0.5 else f"{age_s:.0f} s" if age_s >= 10 else f"{age_s:.1f} s"


def owner_text(status: m.ArmStatus | None) -> str:
    """``operator/cli for 12 s (lease 2.5 s left)``, or ``nobody``."""
    if status is None or status.owner is None:
        return "nobody"
    held = "" if status.owned_s is None else f" for {status.owned_s:.0f} s"
    left = "" if status.lease_left_s is None else f" (lease {status.lease_left_s:.1f} s left)"
    return f"{status.owner}{held}{left}"


def arm_info_html(
    arm: str,
    status: m.ArmStatus | None,
    diag: m.Diag | None,
    online: bool,
    joints_age_s: float,
    contact: tuple[bool, ...],
) -> str:
    """The arm's state in words (``id='arm-<arm>-info'``; one ``data-field`` per line)."""
    if status is not None and status.estopped:
        stop = f"STOPPED: {status.stop_reason or 'no reason given'}"
    else:
        stop = "no" if status is not None else "?"
    joints = [f"j{j}" for j, on in enumerate(contact) if on]
    link = "-" if status is None else status.link
    lines = [
        ("owner", "owner", owner_text(status)),
        ("stop", "stop", stop),
        ("contact", "contact", " ".join(joints) if joints else "none"),
        ("model", "contact model", _model_text(status)),
        ("agent", "agent", "online" if online else "OFFLINE"),
        ("link", "link", f"{link}, joints {age_text(joints_age_s)} old"),
    ]
    if diag is not None:
        lines += [
            ("rate", "feedback", f"{diag.feedback_rate_hz:.1f} Hz"),
            (
                "counters",
                "counted",
                f"relayed {diag.relayed}, malformed {diag.malformed}, refused {diag.rejected}, "
                f"ack timeouts {diag.ack_timeouts}, commands {diag.commands}",
            ),
        ]
    else:
        lines.append(("counters", "counted", "no diag from the agent yet"))
    body = "".join(
        f"<div data-field='{field}'><b>{label}</b>: {html.escape(text)}</div>"
        for field, label, text in lines
    )
    return f"<div id='arm-{html.escape(arm)}-info' style='font-size:0.8em'>{body}</div>"


def _model_text(status: m.ArmStatus | None) -> str:
    """The detector's model of the arm, with what to do about it."""
    model = None if status is None else status.contact_model
    if model == "uncalibrated":
        return "uncalibrated (run fleet calibrate)"
    if model == "partial":
        return "partly calibrated: some joints are not (run fleet calibrate)"
    return model or "-"


def readout_text(angles: npt.NDArray[np.float64], contact: tuple[bool, ...]) -> str:
    """One Markdown line per joint, the angle in bold, contact marked."""
    return "  \n".join(
        # No padding inside the markers: "** 29.1**" is not bold in Markdown, it is literal.
        f"j{j}: **{a:.1f}**°" + (f" {CONTACT_MARK}" if j < len(contact) and contact[j] else "")
        for j, a in enumerate(np.round(angles, 1).tolist())
    )


class ArmPanel:
    """The folder of one arm. ``on_stop(arm)``/``on_reset(event, arm)`` are the fleet panels'
    handlers (the reset opens their confirmation dialog)."""

    def __init__(
        self,
        gui: viser.GuiApi,
        arm: str,
        commander: Commander | None,
        plot_on: bool,
        controls: ArmControls,
        on_stop: Callable[[str], None],
        on_reset: Callable[[viser.GuiEvent, str], None],
    ) -> None:
        self.arm = arm
        self.blocked: bool | None = None
        self.measured: npt.NDArray[np.float64] | None = None
        self.jogged_s = -SLIDER_HOLD_S
        self.readout_text = ""
        self.info_html = ""
        self.stop_button: viser.GuiButtonHandle | None = None
        self.reset_button: viser.GuiButtonHandle | None = None
        self.sliders: list[viser.GuiSliderHandle[float]] = []
        with gui.add_folder(f"Arm {arm}", expand_by_default=False):
            self.info = gui.add_html(arm_info_html(arm, None, None, False, np.inf, ()))
            if controls.stop:
                self.stop_button = gui.add_button(
                    f"Stop {arm}", color="red", icon=viser.Icon.HAND_STOP, hint=f"stop {arm} only"
                )
                self.stop_button.on_click(lambda _e: on_stop(arm))
            if controls.reset:
                self.reset_button = gui.add_button(f"Reset {arm}…", color="gray")
                self.reset_button.on_click(lambda e: on_reset(e, arm))
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
            if not controls.jog or commander is None:
                return  # no sliders at all (the commander would refuse them anyway)
            for joint, (low, high) in enumerate(commander.joint_ranges(arm)):
                slider = gui.add_slider(
                    f"jog j{joint}", min=low, max=high, step=0.5, initial_value=0.0, disabled=True
                )
                slider.on_update(self._on_slide(commander, joint))
                self.sliders.append(slider)
            gui.add_markdown(
                f"Jog: each move goes at most {MAX_JOG_STEP_DEG:g}° from the measured angle, "
                f"one every {JOG_INTERVAL_S:g} s, and takes the arm's lease (a script holding "
                "it refuses the jog, naming itself; the owner line above says who holds it). "
                "The sliders follow the arm."
            )

    def _on_slide(self, commander: Commander, joint: int) -> Callable[[viser.GuiEvent], None]:
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

    def show_info(self, info: str) -> None:
        """Replace the state lines (only when they changed)."""
        if info != self.info_html:
            self.info_html = info
            self.info.content = info

    def show(self, angles: npt.NDArray[np.float64], contact: tuple[bool, ...] = ()) -> None:
        """Refresh the readout, and the sliders unless the operator is using them, from the
        measured angles: a jog always starts from where the arm is."""
        self.measured = angles.copy()
        text = readout_text(angles, contact)
        if text != self.readout_text:
            self.readout_text = text
            self.readout.content = text
        if self.sliders and time.monotonic() - self.jogged_s >= SLIDER_HOLD_S:
            for slider, angle in zip(self.sliders, angles.tolist(), strict=True):
                value = float(np.clip(round(angle * 2) / 2, slider.min, slider.max))
                if value != slider.value:
                    slider.value = value
