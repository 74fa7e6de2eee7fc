"""The operator's console in a real headless Chromium (issue 26 items 6, 8, 11; issue 25's
viewer items): the first view and "Fit view" frame every pose the joint limits allow, alike.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import numpy.typing as npt

from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.record.reader import read_recording
from testkit.browser import Browser
from testkit.harness import FleetHarness, free_port, wait_until
from tests.browser.test_viewer_devices import fleet  # noqa: F401  (router, sim, agent: arm + devices)
from tests.browser.test_viewer_shift import BrowserCamera, open_page, viewer_of
from viewer.app import Viewer
from viewer.camera import FOV_RAD, fit_view, usable_right_edge

WIDE = {"width": 1400, "height": 900}
"""The window where an arm of the dancing demo swung out of the first view's left edge."""


def any_pose_points(viewer: Viewer, poses: int = 300) -> npt.NDArray[np.float64]:
    """The corners of every link's box with every arm at ``poses`` random poses within its
    joint limits (drawn independently of the viewer's own reach grid)."""
    scene = viewer.scene
    rng = np.random.default_rng(7)
    low = np.array([r[0] for r in JOINT_RANGE_DEG])
    high = np.array([r[1] for r in JOINT_RANGE_DEG])
    points = [
        scene.frame_points(rng.uniform(low, high, (len(scene.arms), 7))) for _ in range(poses)
    ]
    # Each arm also at the ends of every joint at once (the extremes a grid may straddle).
    for ends in (low, high, np.where(np.arange(7) % 2 == 0, low, high)):
        points.append(scene.frame_points(np.tile(ends, (len(scene.arms), 1))))
    return np.vstack(points)


def at_the_fit(viewer: Viewer, camera: BrowserCamera) -> bool:
    """The browser's camera is where the viewer frames the fleet's reach for its window."""
    browser_camera = camera.client.camera
    right = usable_right_edge(browser_camera.image_width)
    goal, _ = fit_view(viewer.scene.view_points(), FOV_RAD, browser_camera.aspect, right)
    return bool(np.linalg.norm(np.asarray(browser_camera.position) - goal) < 0.01)


def test_the_first_view_and_fit_view_frame_every_pose_the_limits_allow_alike(
    fleet3_harness: FleetHarness, browser: Browser
) -> None:
    """Framed on the pose of the moment, an arm that then swung out left the view; the first
    view and "Fit view" also framed differently (issue 26 item 11)."""
    fleet3_harness.start_router()
    browser.page.set_viewport_size(WIDE)
    with viewer_of(fleet3_harness) as viewer:
        open_page(browser, viewer.url)
        camera = BrowserCamera(viewer)
        points = any_pose_points(viewer)

        def framed() -> bool:
            return camera.span(points)[0]

        # The initial camera assumed a window; the first report tells this one's, and the
        # viewer frames it once for it.
        wait_until(lambda: at_the_fit(viewer, camera) and framed(), 15.0)
        span = camera.span(points)[1]
        assert span > 0.6, f"the fleet's reach fills only {span:.0%} of the first view"
        first = np.asarray(camera.client.camera.position)

        camera.client.camera.position = (8.0, -9.0, 6.0)  # the operator wanders off
        camera.client.camera.look_at = (3.0, 3.0, 0.0)
        wait_until(lambda: camera.span(points)[1] < 0.3, 10.0)
        reports = camera.reports
        browser.page.get_by_role("button", name="Fit view").click()
        try:
            wait_until(
                lambda: camera.reports > reports and at_the_fit(viewer, camera) and framed(), 15.0
            )
        except AssertionError:
            raise AssertionError(
                f"Fit view put the camera at {camera.client.camera.position}, the first view "
                f"at {tuple(first)}"
            ) from None
        browser.save_page("30-fit-1400")


def animation_frames(browser: Browser, count: int) -> None:
    """Returns once the page has drawn ``count`` more animation frames (viser moves the camera
    by held keys once per frame)."""
    browser.page.evaluate(
        """count => new Promise(done => {
            const step = n => n <= 0 ? done() : requestAnimationFrame(() => step(n - 1));
            step(count);
        })""",
        count,
    )


def azimuth_deg(camera: BrowserCamera) -> float:
    """Where the browser's camera looks from, around the vertical."""
    view = np.asarray(camera.client.camera.position) - np.asarray(camera.client.camera.look_at)
    return float(np.degrees(np.arctan2(view[1], view[0])))


def test_arrow_keys_on_a_focused_jog_slider_jog_and_leave_the_camera_alone(
    fleet_harness: FleetHarness, browser: Browser
) -> None:
    """viser orbits the camera on arrow keys pressed anywhere but a text field; a focused jog
    slider is a <div role=slider>, so jogging an arm from the keyboard also turned the view
    (issue 26 item 6). The control: the same keys with the slider blurred still move the
    camera, and its report arrives."""
    fleet_harness.start_fleet()
    with viewer_of(fleet_harness) as viewer:
        open_page(browser, viewer.url)
        camera = BrowserCamera(viewer)
        wait_until(lambda: camera.client.client_id in viewer._framed, 15.0)
        wait_until(lambda: at_the_fit(viewer, camera), 15.0)
        start_azimuth, start_z = azimuth_deg(camera), float(camera.client.camera.position[2])
        browser.page.get_by_text("Arm a1", exact=True).first.click()
        slider = browser.page.get_by_role("slider").first  # jog j0
        wait_until(lambda: slider.get_attribute("data-disabled") is None, 15.0)
        before = slider.get_attribute("aria-valuenow")
        slider.focus()
        browser.page.keyboard.down("ArrowLeft")
        wait_until(lambda: slider.get_attribute("aria-valuenow") != before, 10.0)
        animation_frames(browser, 40)  # viser would turn the camera on each of them
        browser.page.keyboard.up("ArrowLeft")
        assert viewer.commander is not None
        wait_until(lambda: viewer.commander.answered("a1"), 10.0)  # type: ignore[union-attr]

        # The control: off the slider, a held key moves the camera (E: up; no turn).
        browser.page.evaluate("document.activeElement && document.activeElement.blur()")
        browser.page.keyboard.down("KeyE")
        animation_frames(browser, 20)
        browser.page.keyboard.up("KeyE")
        wait_until(lambda: camera.client.camera.position[2] > start_z + 0.05, 10.0)
        turned = azimuth_deg(camera) - start_azimuth
        assert abs(turned) < 0.5, f"the jog's arrow key turned the camera {turned:.1f} deg"


NARROW = {"width": 1024, "height": 768}
"""The window where the fleet table hid its last columns (issue 26 item 8)."""

GEOMETRY = """() => {
    const box = e => { const r = e.getBoundingClientRect(); return [r.left, r.right, r.height]; };
    const wrap = document.querySelector('#fleet-table').parentElement;
    const fit = [...document.querySelectorAll('button')]
        .find(b => b.innerText.includes('Fit view'));
    const arm = document.querySelector('#fleet-table tr[data-arm] td');
    const heads = document.querySelectorAll('#fleet-table th');
    const idle = {wrap: box(wrap), scrolls: wrap.scrollWidth > wrap.clientWidth, arm: box(arm)};
    wrap.style.maxWidth = '150px';  // a table wider than its panel (long owners, many columns)
    wrap.scrollLeft = wrap.scrollWidth;  // as far right as it goes
    const scrolled = {wrap: box(wrap), scrolls: wrap.scrollWidth > wrap.clientWidth,
                      arm: box(arm), last: box(heads[heads.length - 1])};
    wrap.scrollLeft = 0;
    wrap.style.maxWidth = '';
    const states = [...document.querySelectorAll('#device-table [data-field=state] td')];
    const ids = [...document.querySelectorAll('#device-table [data-device] td')];
    return {panel: box(fit), idle, scrolled, states: states.map(box),
            line: ids.length ? box(ids[0]) : null};
}"""


def inside(cell: list[float], frame: list[float]) -> bool:
    return cell[0] >= frame[0] - 1 and cell[1] <= frame[1] + 1


def test_the_fleet_and_devices_tables_fit_the_panel_at_1024_px(
    fleet: FleetHarness,  # noqa: F811
    browser: Browser,
) -> None:
    """The fleet table was 626 px in a 364 px panel with no visible scrollbar (owner and age
    out of view); the devices' state wrapped to 4-5 lines (issue 26 item 8, issue 25)."""
    browser.page.set_viewport_size(NARROW)
    with viewer_of(fleet) as viewer:
        open_page(browser, viewer.url)
        page = browser.page
        wait_until(lambda: page.locator("#fleet-table tr[data-arm]").count() == 1, 20.0)
        wait_until(lambda: "walk" in page.locator("#device-table").inner_text(), 30.0)
        geometry = page.evaluate(GEOMETRY)
        browser.save_page("31-tables-1024")
        idle, scrolled = geometry["idle"], geometry["scrolled"]
        assert inside(idle["wrap"], geometry["panel"]), geometry
        assert inside(idle["arm"], idle["wrap"]), geometry
        assert not idle["scrolls"], f"an idle fleet's table does not fit the panel: {geometry}"
        # Wider than its frame, it scrolls inside it, and the arm id stays in view.
        assert scrolled["scrolls"] and inside(scrolled["last"], scrolled["wrap"]), geometry
        assert inside(scrolled["arm"], scrolled["wrap"]), f"the arm id scrolled away: {geometry}"
        for state in geometry["states"]:
            assert state[2] < 1.6 * geometry["line"][2], f"a device's state wraps: {geometry}"


def test_the_replay_button_shows_the_icon_of_what_a_click_does(
    tmp_path: Path, browser: Browser
) -> None:
    """The button read "Pause" under a play icon while a recording played."""
    from testkit.recordings import write_recording
    from viewer.replay import replay_source

    path = tmp_path / "shift.mcap"
    write_recording(path)
    with Viewer(replay=replay_source(read_recording(path)), port=free_port()) as viewer:
        browser.page.goto(viewer.url)
        shown = """() => {
            const b = [...document.querySelectorAll('button')]
                .find(b => b.textContent.includes('Pause'));
            const svg = b && b.querySelector('svg');
            return svg ? svg.getAttribute('class') : (b ? 'no svg: ' + b.outerHTML : null);
        }"""

        clicked = [0.0]

        def pause_icon() -> str | None:
            """The Pause button's icon while it plays (5 s); press Play again if the click
            came before the page was served, or the recording already played to its end. Not
            again before the page could show the last click's answer: on a loaded host two
            clicks 0.2 s apart paused what the first one started, and so on for 30 s."""
            icon = browser.page.evaluate(shown)
            if icon is None and time.monotonic() - clicked[0] > 3.0:
                play = browser.page.get_by_role("button", name="Play")
                if play.count():
                    play.first.click()
                    clicked[0] = time.monotonic()
            return icon  # type: ignore[no-any-return]

        icon = wait_until(pause_icon, 30.0, interval_s=0.2)
        assert "icon-tabler-player-pause" in icon, f"the Pause button shows {icon}"
