"""The viewer for a shift (issue 15), in a real headless Chromium against real processes: the
camera frames the fleet (at start and on "Fit view"), a jog from the browser is one bounded step
from the measured pose under the viewer's lease (and the arm's panel says who holds it), each
arm stops and resets from its own folder, the event log shows stops, refusals and contacts,
and a recording replays with a timeline that scrubs the arms and no command control at all.
"""

from __future__ import annotations

import os
import re
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import numpy.typing as npt

from fleet.record.layout import layout_of
from fleet.record.recorder import Recorder
from fleet.wire import keys
from fleet.wire import messages as m
from testkit.browser import Browser
from testkit.harness import FleetHarness, free_port, wait_until
from testkit.kinds import DEVICES
from viewer.app import Viewer
from viewer.camera import UP, camera_axes, usable_right_edge

# ---------------------------------------------------------------------- helpers

SHARE_ICON = "svg.tabler-icon-share"
"""viser's share button (1.1.1) draws this icon; it asks for a public tunnel to the viewer."""


@contextmanager
def viewer_of(harness: FleetHarness, principal: str = "operator") -> Iterator[Viewer]:
    """The viewer in this process (its browser's camera is readable here), acting as
    ``principal``."""
    with Viewer(harness.inventory.with_principal(principal), port=free_port()) as viewer:
        yield viewer


def open_page(browser: Browser, url: str) -> None:
    browser.page.goto(url)
    browser.page.locator("canvas").first.wait_for(timeout=30_000)
    browser.page.get_by_role("button", name="Fit view").wait_for(timeout=30_000)


def expand(browser: Browser, folder: str) -> None:
    """Open a collapsed GUI folder by its title."""
    browser.page.get_by_text(folder, exact=True).first.click()


def event_rows(browser: Browser) -> list[tuple[str, str]]:
    """(kind, text) of every row of the event log, newest first."""
    rows = browser.page.locator("#event-log tr[data-kind]")
    return [
        (rows.nth(i).get_attribute("data-kind") or "", rows.nth(i).inner_text())
        for i in range(rows.count())
    ]


def arm_info(browser: Browser, arm: str, field: str) -> str:
    node = browser.page.locator(f"#arm-{arm}-info [data-field='{field}']")
    return node.inner_text() if node.count() else ""


def table_row(browser: Browser, arm: str) -> str:
    row = browser.page.locator(f"tr[data-arm='{arm}']")
    return row.inner_text() if row.count() else ""


class BrowserCamera:
    """The camera as the browser reports it (viser's camera messages from the page)."""

    def __init__(self, viewer: Viewer) -> None:
        self.viewer = viewer
        self.reports = 0
        self._lock = threading.Lock()
        self.client = wait_until(lambda: next(iter(viewer.server.get_clients().values()), None), 30)
        self.client.camera.on_update(self._on_report)
        wait_until(lambda: self.client.camera.update_timestamp != 0.0, 30.0)

    def _on_report(self, _camera: object) -> None:
        with self._lock:
            self.reports += 1

    def span(self, points: npt.NDArray[np.float64]) -> tuple[bool, float]:
        """(every point inside the part of the view the control panel leaves free, the larger
        fraction of that part's width or height the points span) for the browser's camera."""
        camera = self.client.camera
        right_edge = usable_right_edge(camera.image_width)
        position, look_at = np.asarray(camera.position), np.asarray(camera.look_at)
        back, right, up = camera_axes(position - look_at, UP)
        rel = points - position
        depth = -(rel @ back)
        tan_v = np.tan(camera.fov / 2.0)
        x = (rel @ right) / depth / (tan_v * camera.aspect)
        y = (rel @ up) / depth / tan_v
        inside = bool(
            np.all(depth > 0) and np.all((x >= -1) & (x <= right_edge)) and np.all(np.abs(y) <= 1)
        )
        return inside, float(max(np.ptp(x) / (1.0 + right_edge), np.ptp(y) / 2.0))


def _framed(
    camera: BrowserCamera, points: npt.NDArray[np.float64], what: str, after_reports: int = -1
) -> float:
    """Wait until one report of the browser's camera (after ``after_reports`` of them) has
    every point inside and spanning over 60 % of the view; that span. Inside and spanning in
    the same report: the browser reports position and look-at apart, and a report between the
    two has the new position with the old look-at."""
    seen: list[tuple[bool, float]] = []

    def framed() -> bool:
        if camera.reports <= after_reports:
            return False
        seen.append(camera.span(points))
        return seen[-1][0] and seen[-1][1] > 0.6

    try:
        wait_until(framed, 15.0)
    except AssertionError:
        why = f"{what} does not frame every arm: (inside, span) {seen[-3:]}"
        raise AssertionError(why) from None
    return seen[-1][1]


def arm_points(viewer: Viewer) -> npt.NDArray[np.float64]:
    """The points the viewer frames: every arm's whole reach (and its label), in the world."""
    return viewer.scene.view_points()


# ---------------------------------------------------------------------- fit, share


def check_the_fit(browser: Browser, viewer: Viewer) -> None:
    """The camera frames the fleet at start and on "Fit view" (the arms filled about 15 % of
    the first view, issue 15); the page has no share button."""
    assert browser.page.locator(SHARE_ICON).count() == 0  # no share button (a public tunnel)
    camera = BrowserCamera(viewer)
    points = arm_points(viewer)
    span = _framed(camera, points, "the first view")
    print(f"first view: the arms span {span:.0%} of it")
    browser.save_page("10-fit-at-start")

    # The operator wanders off (zooms out and pans away).
    camera.client.camera.position = (8.0, -9.0, 6.0)
    camera.client.camera.look_at = (3.0, 3.0, 0.0)
    wait_until(lambda: camera.span(points)[1] < 0.3, 10.0)
    reports = camera.reports
    browser.page.get_by_role("button", name="Fit view").click()
    # The server sets the camera at once; the browser's own report of it is the proof.
    span = _framed(camera, points, "Fit view", after_reports=reports)
    print(f"after Fit view: the arms span {span:.0%} of the view")
    browser.save_page("11-fit-after-button")


def test_the_share_selector_finds_viser_s_share_button_where_it_is_on(browser: Browser) -> None:
    """The control for the check above: a plain viser server shows the share button, and the
    selector finds it (so "no share button" is not a selector that matches nothing)."""
    import viser

    port = free_port()
    plain = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    try:
        plain.gui.add_button("hello")
        browser.page.goto(f"http://127.0.0.1:{port}/")
        browser.page.get_by_role("button", name="hello").wait_for(timeout=30_000)
        wait_until(lambda: browser.page.locator(SHARE_ICON).count() > 0, 10.0)
    finally:
        plain.stop()


# ---------------------------------------------------------------------- jog


def test_a_jog_from_the_browser_is_one_bounded_step_under_the_viewers_lease(
    fleet_harness: FleetHarness, browser: Browser
) -> None:
    from viewer.commands import MAX_JOG_STEP_DEG

    client = fleet_harness.start_fleet()

    def joint0() -> float:
        joints = client.snapshot(["a1"], wait_s=0.5)["a1"][1]
        assert joints is not None
        return joints.angles_deg[0]

    with viewer_of(fleet_harness) as viewer:
        open_page(browser, viewer.url)
        expand(browser, "Arm a1")
        assert arm_info(browser, "a1", "owner") == "owner: nobody"
        slider = browser.page.get_by_role("slider").first  # jog j0
        wait_until(lambda: slider.get_attribute("data-disabled") is None, 15.0)
        start = joint0()
        slider.focus()
        slider.press("End")  # the slider's far end: 100+ degrees from the arm
        wait_until(lambda: abs(joint0() - start) > MAX_JOG_STEP_DEG * 0.8, 10.0)
        # Someone else is refused while the viewer holds the arm (its lease lasts lease_s after
        # the jog), and told who holds it; the arm's panel and the table say it too.
        other = client.command("a1", m.MoveJoint(joint=0, angle_deg=start, owner="script"))
        assert not other.ok and other.error is not None
        assert other.error.code == m.ErrorCode.LEASE_EXISTS and "viewer@" in other.error.message

        time.sleep(1.0)  # it settles where the one step ends, not at the slider's end
        assert abs(joint0() - (start + MAX_JOG_STEP_DEG)) < 1.0, (start, joint0())

        # The lease lasts 3 s after a jog, and a loaded browser may take longer than that to
        # draw the owner line: a half-degree jog every 2 s (the sliders follow the arm again
        # 1.5 s after a touch, so it starts from the measured pose) keeps the lease held.
        def shown_owner() -> str | None:
            text = arm_info(browser, "a1", "owner")
            if "viewer@" in text:
                return text
            slider.press("ArrowLeft")
            return None

        owner = wait_until(shown_owner, 20.0, interval_s=2.0)
        assert owner.startswith("owner: operator/viewer@") and f":{os.getpid()}" in owner
        assert "lease" in owner

        def table_owner() -> bool:  # the table too, the lease kept as above
            if "viewer@" in table_row(browser, "a1"):
                return True
            slider.press("ArrowLeft")
            return False

        wait_until(table_owner, 20.0, interval_s=2.0)
        browser.save_page("12-jog")


# ---------------------------------------------------------------------- stop, reset, events


def test_the_fit_then_one_arms_stop_and_reset_and_the_event_log(
    fleet3_harness: FleetHarness, browser: Browser
) -> None:
    """One fleet of three for both (a fleet and a page cost 15 s on the browser tests' worker)."""
    client = fleet3_harness.start_fleet()
    fleet3_harness.start_coordinator()  # its estop/report gives each stop's timing in the log
    with viewer_of(fleet3_harness) as viewer:
        open_page(browser, viewer.url)
        check_the_fit(browser, viewer)
        expand(browser, "Arm a2")
        browser.page.get_by_role("button", name="Stop a2").click()
        wait_until(lambda: "STOPPED" in table_row(browser, "a2"), 10.0)
        time.sleep(0.5)
        assert "STOPPED" not in table_row(browser, "a1") + table_row(browser, "a3")
        info = wait_until(
            lambda: (t := arm_info(browser, "a2", "stop")).startswith("stop: ST") and t, 5
        )
        assert "stop a2 pressed in the viewer" in info
        rows = wait_until(lambda: len(event_rows(browser)) >= 2 and event_rows(browser), 5.0)
        assert ("stop", "stop requested by viewer: stop a2 pressed in the viewer") in [
            (k, t.split("\t")[-1].strip()) for k, t in rows
        ], rows
        assert any(k == "stop" and "a2" in t and "STOPPED (latched)" in t for k, t in rows)
        # Once a2 is still, the coordinator's report of the stop gives its timing, named.
        timing = wait_until(
            lambda: [t for k, t in event_rows(browser) if k == "stop" and "still within" in t],
            10.0,
        )
        assert "stop by viewer: 1 arm still within" in timing[0] and "(slowest a2)" in timing[0]

        # A command for the stopped arm is refused by its agent: the log says so (from diag).
        refused = client.command("a2", m.MoveJoint(joint=0, angle_deg=5.0))
        assert not refused.ok
        wait_until(lambda: any(k == "refused" and "a2" in t for k, t in event_rows(browser)), 5)

        # The arm's own reset, through its confirmation.
        browser.page.get_by_role("button", name="Reset a2…").click()
        browser.page.get_by_role("button", name="Reset a2", exact=True).click()
        wait_until(lambda: "STOPPED" not in table_row(browser, "a2"), 10.0)
        wait_until(lambda: any(k == "released" for k, _t in event_rows(browser)), 5.0)
        assert any(k == "reset" and "a2" in t for k, t in event_rows(browser))
        browser.save_page("13-stop-reset-events")

        # A contact: the simulated arm meets an obstacle; the log and the arm's panel show it.
        fault = b'{"op": "obstacle", "joint": 1, "angle_deg": 15.0, "compliance": 0.05}'
        replies = list(client.session.get(client.keys.arm("a1", keys.SIM_FAULT), payload=fault))
        assert replies and replies[0].ok is not None
        client.command("a1", m.MoveJoint(joint=1, angle_deg=45.0))
        expand(browser, "Arm a1")
        wait_until(
            lambda: any(k == "contact" and "j1 contact" in t for k, t in event_rows(browser)), 10
        )
        # The arm's folder shows the contact while it lasts; the agent's force limit retracts
        # the target, so it may be released before a slow browser draws it.
        wait_until(
            lambda: (
                "j1" in arm_info(browser, "a1", "contact")
                or any(
                    k == "contact" and "j1 contact released" in t for k, t in event_rows(browser)
                )
            ),
            10.0,
        )
        browser.save_page("14-contact-event")
    # The log is newest first, with wall-clock times.
    times = [t.split("\t")[0] for _k, t in rows]
    assert all(re.fullmatch(r"\d\d:\d\d:\d\d", when) for when in times), times


# ---------------------------------------------------------------------- replay


def connected_to(pid: int, port: int) -> bool:
    """True when ``pid`` has an established TCP connection to loopback ``port``."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    for table in ("tcp", "tcp6"):
        for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            remote_port = int(fields[2].rsplit(":", 1)[1], 16)
            if fields[9] in inodes and fields[3] == "01" and remote_port == port:
                return True
    return False


def test_a_recording_replays_with_a_timeline_and_no_command_control(
    fleet_harness: FleetHarness, browser: Browser, tmp_path: Path
) -> None:
    h = fleet_harness
    client = h.start_fleet()
    path = tmp_path / "shift.mcap"
    layout = layout_of(h.inventory)
    with Recorder(client.session, client.keys, ["a1"], path, layout=layout):
        for target in (60.0, -30.0):
            reply = client.command(
                "a1", m.MoveJoint(joint=0, angle_deg=target, wait_reached=True, timeout_s=15.0)
            )
            assert reply.ok, reply.error
            time.sleep(0.8)
    argv = ["-m", "fleet.cli.main", "viewer", "--port", str(free_port()), "--replay", str(path)]
    process = h.start("replay-viewer", argv, inventory=False)  # no inventory: the file says
    line = wait_until(
        lambda: (
            next(
                (ln for ln in h.log("replay-viewer").splitlines() if "d1-fleet viewer: http" in ln),
                None,
            )
            or (process.poll() is not None and "exited")
        ),
        30.0,
    )
    assert line != "exited", h.log("replay-viewer")
    url = line.split("d1-fleet viewer: ", 1)[1].split()[0]
    page = browser.page
    open_page(browser, url)
    page.get_by_role("button", name="Play").wait_for(timeout=15_000)
    # Nothing that commands: no STOP ALL, no arm stop or reset, no jog slider; no Zenoh.
    for name in ("STOP ALL", "Reset stop…", "Stop a1", "Reset a1…"):
        assert page.get_by_role("button", name=name).count() == 0, name
    assert page.get_by_role("slider").count() == 1  # the timeline only
    assert not connected_to(process.pid, h.port)

    def position() -> float:
        node = page.locator("#replay-position")
        return float(node.get_attribute("data-position") or "nan") if node.count() else -1.0

    expand(browser, "Arm a1")
    timeline = page.get_by_role("slider").first
    timeline.focus()
    timeline.press("Home")
    wait_until(lambda: position() == 0.0, 10.0)
    for _ in range(5):  # 0.5 s in: the first joints sample may come after the first status
        timeline.press("ArrowRight")
    wait_until(lambda: position() >= 0.45, 10.0)
    readout = page.get_by_text(re.compile(r"^j0: "))
    start_text = wait_until(lambda: readout.count() and readout.first.inner_text(), 10.0)
    time.sleep(1.0)
    at_start = browser.canvas("15-replay-start")
    timeline.press("End")
    wait_until(lambda: position() > 3.0, 10.0)
    end_text = wait_until(lambda: re.search(r"-(29|30)\.\d", readout.first.inner_text()), 10.0)
    assert end_text and start_text != readout.first.inner_text()
    time.sleep(1.0)
    at_end = browser.canvas("16-replay-end")
    moved = int((np.abs(at_end - at_start).max(axis=2) > 30).sum())
    assert moved > 200, f"scrubbing to the end changed {moved} pixels only"
    browser.save_page("17-replay-page")

    # Play from the start: the position advances; pause: it stays.
    timeline.press("Home")
    wait_until(lambda: position() == 0.0, 10.0)
    page.get_by_role("button", name="Play").click()
    wait_until(lambda: position() > 1.0, 10.0)
    page.get_by_role("button", name="Pause").click()

    def held() -> float | None:
        # Paused, and the position no longer moves (on a loaded host the page said "paused"
        # while a late frame of the playing timeline was still to come).
        if "paused" not in page.locator("#replay-position").inner_text():
            return None
        first = position()
        time.sleep(0.5)
        return first if abs(position() - first) < 0.05 else None

    paused = wait_until(held, 15.0)
    time.sleep(1.0)
    assert abs(position() - paused) < 0.3
    assert process.poll() is None, h.log("replay-viewer")


# ---------------------------------------------------------------------- devices


def test_the_viewer_shows_a_mounted_gripper_opening_and_the_g1s_fsm(
    tmp_path: Path, browser: Browser
) -> None:
    """Issue 14: a Dex1-1 mounted on a1 opens and closes a1's fingers in the scene, and the
    G1's FSM shows in the Devices table."""
    from fleet.dex1.messages import GripperMove
    from testkit.collect import agent_token

    extra = DEVICES  # (testkit/kinds.py: simulated at the lab's rates)
    with FleetHarness(tmp_path, arms=1, extra=extra) as harness:
        harness.start_router()
        harness.start_sim()
        harness.start_agent()
        harness.start("devices", ["-m", "edge_agent", "--device", "gl", "--device", "h1"])
        client = harness.client()
        wait_until(lambda: harness.all_links_ok(client), 30.0)
        with viewer_of(harness) as viewer:
            open_page(browser, viewer.url)
            page = browser.page

            def row(device: str) -> str:
                found = page.locator(f"#device-table [data-device='{device}']")
                return found.inner_text() if found.count() else ""

            wait_until(lambda: "walk" in row("h1"), 30.0)  # fsm 500, named from seed 004
            wait_until(lambda: agent_token(client, "gripper", "gl"), 30.0)
            assert "g1" in row("h1") and "a1" in row("gl")

            def fingers() -> float:
                return float(viewer.scene._drawn_deg[0, 6])

            closed, fully_open = viewer.scene.gripper_deg[0]

            def opening_shown() -> float | None:
                """The opening % the table shows (``open  90.0 %``), or None."""
                found = re.search(r"open\s+(-?[\d.]+) %", row("gl"))
                return float(found.group(1)) if found else None

            for pct in (90.0, 10.0):
                assert client.device_command("gl", GripperMove(open_pct=pct)).ok
                # Near the target, not its digits: the gripper settles within its tolerance
                # (a loaded run's table never showed "90" in 10 s).
                wait_until(lambda p=pct: abs((opening_shown() or -99.0) - p) < 1.5, 15.0)
                want = closed + pct / 100.0 * (fully_open - closed)
                wait_until(lambda w=want: abs(fingers() - w) < 2.0, 10.0)
                browser.canvas(f"18-gripper-{pct:.0f}")
            browser.save_page("19-devices")
