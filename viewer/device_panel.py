"""One device's folder in the viewer (a gripper, a G1): its state line, its own stop and reset,
and the kind's controls: the gripper an opening slider, the G1 its safe mode buttons (damp,
stop move). Every command goes through ``Commander.device``, under the viewer's lease like the
arm jog (a script holding the device refuses it, 3207, naming itself).

What a folder offers follows the viewer (``ArmControls``): a replay nothing, a read-only
(observer) viewer the stop only, an operator's viewer stop, reset (confirmed on the server, see
viewer/panels.py) and the kind's controls. ``CONTROLS`` is the one table of what each kind
brings: a new kind adds one entry here.
"""

from __future__ import annotations

import html
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import viser

from fleet.dex1.messages import GripperMove
from fleet.g1.messages import Damp, StopMove
from fleet.wire import keys
from fleet.wire.messages import DeviceCommand
from viewer.arm_panel import SLIDER_HOLD_S, ArmControls, age_text
from viewer.commands import Commander
from viewer.state import DeviceView


@dataclass(frozen=True)
class Slider:
    """A slider that sends ``command(value)``; it follows ``measured(state)`` when untouched."""

    label: str
    low: float
    high: float
    step: float
    command: Callable[[float], DeviceCommand]
    measured: Callable[[Any], float]


@dataclass(frozen=True)
class Button:
    """A button that sends ``command()``. Always enabled: the buttons lead to a safer state
    (the agent allows them under a stop, damping even without state); a refusal is shown."""

    label: str
    hint: str
    command: Callable[[], DeviceCommand]


@dataclass(frozen=True)
class KindControls:
    """What one kind's folder offers beyond stop and reset."""

    title: str
    sliders: tuple[Slider, ...] = ()
    buttons: tuple[Button, ...] = ()


CONTROLS: dict[str, KindControls] = {
    keys.GRIPPER: KindControls(
        "Gripper",
        sliders=(
            Slider(
                "opening %",
                0.0,
                100.0,
                1.0,
                lambda value: GripperMove(open_pct=value),
                lambda state: float(state.opening_pct),
            ),
        ),
    ),
    keys.G1: KindControls(
        "G1",
        buttons=(
            Button("Damp", "damping (FSM 1): the robot goes limp and sinks", Damp),
            Button("Stop move", "end any walking (velocity 0, balance stand)", StopMove),
        ),
    ),
}


def device_info_html(view: DeviceView) -> str:
    """The device's state in words (``id='device-<id>-info'``; one ``data-field`` per line)."""
    state = view.state
    if state is not None and getattr(state, "estopped", False):
        stop = f"STOPPED: {getattr(state, 'stop_reason', None) or 'no reason given'}"
    else:
        stop = "no" if state is not None else "?"
    link = "-" if state is None else str(getattr(state, "link", "?"))
    lines = [
        ("stop", "stop", stop),
        ("link", "link", f"{link}, state {age_text(view.age_s)} old"),
        ("state", "state", view.summary or "no state yet"),
    ]
    body = "".join(
        f"<div data-field='{field}'><b>{label}</b>: {html.escape(text)}</div>"
        for field, label, text in lines
    )
    return f"<div id='device-{html.escape(view.device)}-info' style='font-size:0.8em'>{body}</div>"


class DevicePanel:
    """The folder of one device. ``on_stop(device)``/``on_reset(event, device)`` are the fleet
    panels' handlers (the reset opens their confirmation dialog)."""

    def __init__(
        self,
        gui: viser.GuiApi,
        device: str,
        kind: str,
        commander: Commander | None,
        controls: ArmControls,
        on_stop: Callable[[str], None],
        on_reset: Callable[[viser.GuiEvent, str], None],
    ) -> None:
        self.device = device
        self.kind = kind
        self.blocked: bool | None = None
        self.touched_s = -SLIDER_HOLD_S
        self.info_html = ""
        self.stop_button: viser.GuiButtonHandle | None = None
        self.reset_button: viser.GuiButtonHandle | None = None
        self.sliders: list[tuple[Slider, viser.GuiSliderHandle[float]]] = []
        self.buttons: list[tuple[Button, viser.GuiButtonHandle]] = []
        own = CONTROLS.get(kind, KindControls(kind))
        with gui.add_folder(f"{own.title} {device}", expand_by_default=False):
            self.info = gui.add_html(device_info_html(DeviceView(device, kind, "", None, 1e9, "")))
            if controls.stop:
                self.stop_button = gui.add_button(
                    f"Stop {device}",
                    color="red",
                    icon=viser.Icon.HAND_STOP,
                    hint=f"stop {device} only",
                )
                self.stop_button.on_click(lambda _e: on_stop(device))
            if controls.reset:
                self.reset_button = gui.add_button(f"Reset {device}…", color="gray")
                self.reset_button.on_click(lambda e: on_reset(e, device))
            if not controls.jog or commander is None:
                return  # stop only (the commander would refuse the rest anyway)
            for spec in own.sliders:
                slider = gui.add_slider(
                    f"{spec.label}",
                    min=spec.low,
                    max=spec.high,
                    step=spec.step,
                    initial_value=spec.low,
                    disabled=True,
                )
                slider.on_update(self._on_slide(commander, spec))
                self.sliders.append((spec, slider))
            for spec in own.buttons:
                button = gui.add_button(spec.label, hint=spec.hint)
                button.on_click(self._on_button(commander, spec))
                self.buttons.append((spec, button))
            if own.sliders or own.buttons:
                gui.add_markdown(
                    f"Takes {device}'s lease as this viewer (a script holding it refuses, "
                    "naming itself)."
                )

    def _on_slide(self, commander: Commander, spec: Slider) -> Callable[[viser.GuiEvent], None]:
        def on_update(event: viser.GuiEvent) -> None:
            if event.client is None or self.blocked:
                return  # our own sync from the state, or a stale drag
            self.touched_s = time.monotonic()
            commander.device(self.device, spec.command(float(event.target.value)))

        return on_update

    def _on_button(self, commander: Commander, spec: Button) -> Callable[[viser.GuiEvent], None]:
        def on_click(_event: viser.GuiEvent) -> None:
            commander.device(self.device, spec.command())

        return on_click

    def update(self, view: DeviceView) -> None:
        """Refresh the state line, disable the sliders while the device is stopped or stale,
        and let them follow the device unless the operator just used them."""
        info = device_info_html(view)
        if info != self.info_html:
            self.info_html = info
            self.info.content = info
        state = view.state
        stale = state is None or getattr(state, "link", "ok") != "ok" or view.age_s > 3.0
        stopped = bool(state is not None and getattr(state, "estopped", False))
        blocked = stale or stopped
        if blocked != self.blocked:
            self.blocked = blocked
            for _spec, slider in self.sliders:
                slider.disabled = blocked
        if state is None or time.monotonic() - self.touched_s < SLIDER_HOLD_S:
            return
        for spec, slider in self.sliders:
            step = round(spec.measured(state) / spec.step) * spec.step
            value = min(max(step, spec.low), spec.high)
            if value != slider.value:
                slider.value = value
