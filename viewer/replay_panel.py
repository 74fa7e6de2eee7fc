"""The replay's timeline controls: play/pause, a scrub slider, the speed, where we are, and how
many recorded samples did not decode (a damaged or hostile file: skipped, never drawn).

The controls only ask the timeline (viewer/replay.py); the render thread moves it, and
``update`` (panel rate) moves the slider along while playing. A slider update that came from
the server itself (``event.client`` None) is not a scrub.
"""

from __future__ import annotations

import math
import time

import viser

from viewer.replay import SPEEDS, ReplayTimeline


def speed_label(speed: float) -> str:
    """``1x``, ``0.25x``."""
    return f"{speed:g}x"


class ReplayControls:
    """The "Replay" folder of a replay viewer."""

    def __init__(self, gui: viser.GuiApi, timeline: ReplayTimeline) -> None:
        self.timeline = timeline
        source = timeline.source
        with gui.add_folder("Replay"):
            note = (
                ""
                if source.layout_recorded
                else (
                    " This recording keeps no layout (made by an older `fleet record`): the arms "
                    "stand in a row, not where they stood."
                )
            )
            devices = source.layout.devices
            beside = f", {len(devices)} devices ({', '.join(devices)})" if devices else ""
            gui.add_markdown(
                f"Replay of `{source.path}`: {len(timeline.arms)} arms{beside}, "
                f"{timeline.duration_s:.1f} s. Nothing here commands an arm.{note}"
            )
            self.play = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY)
            self.play.on_click(lambda _e: self._toggle())
            self.slider = gui.add_slider(
                "time (s)",
                min=0.0,
                max=max(math.ceil(timeline.duration_s * 10.0) / 10.0, 0.1),
                step=0.1,
                initial_value=0.0,
            )
            self.slider.on_update(self._on_scrub)
            self.speed = gui.add_dropdown(
                "speed", options=[speed_label(s) for s in SPEEDS], initial_value="1x"
            )
            self.speed.on_update(self._on_speed)
            self.where = gui.add_html("")
        self._shown: tuple[bool, float, int] | None = None

    def _toggle(self) -> None:
        self.timeline.set_playing(not self.timeline.playing)

    def _on_scrub(self, event: viser.GuiEvent) -> None:
        if event.client is not None:  # the operator's hand, not our own update below
            self.timeline.request_seek(float(self.slider.value))

    def _on_speed(self, _event: viser.GuiEvent) -> None:
        by_label = {speed_label(s): s for s in SPEEDS}
        speed = by_label.get(str(self.speed.value))
        if speed is not None:
            self.timeline.set_speed(speed)

    def update(self) -> None:
        """Follow the timeline: the button's label, the slider, the time readout."""
        timeline = self.timeline
        malformed = timeline.state.malformed
        shown = (timeline.playing, round(timeline.position_s, 1), malformed)
        if shown == self._shown:
            return
        self._shown = shown
        # The icon says what a click does, as the label does (it kept the play icon). The
        # caller groups these updates (server.atomic()): a page that drew the new label under
        # the old icon for a moment showed "Pause" under a play icon.
        self.play.label = "Pause" if timeline.playing else "Play"
        self.play.icon = viser.Icon.PLAYER_PAUSE if timeline.playing else viser.Icon.PLAYER_PLAY
        self.slider.value = min(max(shown[1], self.slider.min), self.slider.max)
        wall = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(timeline.position_wall_ns / 1e9))
        skipped = (
            f"<div id='replay-malformed' data-count='{malformed}' style='color:#b00'>"
            f"{malformed} recorded samples did not decode: skipped (see the log)</div>"
            if malformed
            else ""
        )
        self.where.content = (
            f"<div id='replay-position' data-position='{timeline.position_s:.2f}' "
            f"style='font-size:0.8em'>{timeline.position_s:.1f} s of "
            f"{timeline.duration_s:.1f} s · recorded {wall} · "
            f"{'playing' if timeline.playing else 'paused'} at "
            f"{speed_label(timeline.speed)}</div>{skipped}"
        )
