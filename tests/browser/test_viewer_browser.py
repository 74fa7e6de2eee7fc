"""The viewer in a real headless Chromium (Debian's, driven by playwright; no browser downloads),
against a fleet of real processes: the 3D canvas draws and moves, STOP ALL and the confirmed reset
reach the key space, a killed agent shows as offline, the page needs the printed token, a page of
another origin cannot open the viewer's WebSocket, and the page loads nothing from elsewhere.
Screenshots are kept under artifacts/viewer/.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
import zenoh
from viser import _messages
from websockets.sync.client import ClientConnection

from fleet.client import FleetClient
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.session import open_client
from testkit.browser import ARTIFACTS, Browser
from testkit.harness import FleetHarness, free_port, wait_until
from testkit.sockets import loopback_only, ws


def start_viewer(harness: FleetHarness, *options: str) -> str:
    """``fleet viewer`` as its own process; returns the URL it printed (the real port and this
    run's token)."""
    argv = ["-m", "fleet.cli.main", "viewer", "--port", str(free_port()), *options]
    harness.start("viewer", argv)
    line = wait_until(
        lambda: (
            next(
                (ln for ln in harness.log("viewer").splitlines() if "d1-fleet viewer: http" in ln),
                None,
            )
            or (harness.processes["viewer"].poll() is not None and "exited")
        ),
        30.0,
    )
    assert line != "exited", harness.log("viewer")
    return line.split("d1-fleet viewer: ", 1)[1].split()[0]


def open_viewer(browser: Browser, url: str, arms: list[str]) -> None:
    assert url.startswith("http://127.0.0.1:") and "/?token=" in url
    browser.page.goto(url)
    assert browser.page.url == url.split("?")[0]  # entered: the token left the address bar
    browser.page.locator("canvas").first.wait_for(timeout=30_000)
    wait_until(lambda: all(browser.arm_online(a) == "yes" for a in arms), 30.0)
    time.sleep(1.0)  # let the first frames render (swiftshader is slow); all asserts poll


def not_blank(image: np.ndarray) -> bool:
    colours = len(np.unique(image.reshape(-1, 3), axis=0))
    return bool(image.std() > 5.0 and colours > 50)


def changed_canvas(
    browser: Browser, before: np.ndarray, step: int, diffs: list[int]
) -> tuple[np.ndarray] | None:
    """A new canvas screenshot (in a 1-tuple) if it differs from ``before`` in > 200 pixels."""
    now = browser.canvas(f"02-a1-move-{step}")
    diffs.append(int((np.abs(now - before).max(axis=2) > 30).sum()))
    return (now,) if diffs[-1] > 200 else None


def _reached(client: FleetClient, arm: str, target: list[float], tol_deg: float = 2.0) -> bool:
    """The arm's newest joints are within ``tol_deg`` of ``target``."""
    _status, joints = client.snapshot([arm], wait_s=1.0)[arm]
    return joints is not None and all(
        abs(a - t) <= tol_deg for a, t in zip(joints.angles_deg, target, strict=False)
    )


def test_canvas_draws_the_fleet_moving_and_stop_all_reaches_the_key_space(
    fleet3_harness: FleetHarness, browser: Browser
) -> None:
    harness = fleet3_harness
    client = harness.start_fleet()
    url = start_viewer(harness, "--principal", "operator")  # may reset (and jog)
    stops: list[m.StopRequest] = []
    lock = threading.Lock()

    def on_stop(sample: zenoh.Sample) -> None:
        with lock:  # a zenoh thread: decode, store, return
            stops.append(payloads.STOP.decode(sample.payload.to_bytes()))

    space = keys.KeySpace(harness.inventory.fleet)
    with open_client(harness.inventory.endpoints) as session:
        subscriber = session.declare_subscriber(space.estop, on_stop)
        open_viewer(browser, url, ["a1", "a2", "a3"])
        first = browser.canvas("01-fleet-at-rest")
        assert not_blank(first), "the 3D canvas is blank"
        browser.save_page("01-page")

        # Move a1 twice: each move must show up on the canvas as a different picture.
        frames_before, t0 = browser.frames, time.monotonic()
        diffs: list[int] = []
        shot = first
        for step, target in enumerate(([60.0, 40.0, -60.0, 30.0, 45.0, 20.0, 50.0], [0.0] * 7)):
            reply = client.command("a1", m.MoveJoints(angles_deg=target, mode=1))
            assert reply.ok, reply.error
            # The move's end, then its picture: a picture taken as the first move had barely
            # begun, compared with the arm back at zero, differed by too few pixels (two
            # fresh-clone runs).
            wait_until(lambda t=target: _reached(client, "a1", t), 15.0)
            shot = wait_until(lambda s=shot, k=step: changed_canvas(browser, s, k, diffs), 15.0)[0]
        rate = (browser.frames - frames_before) / (time.monotonic() - t0)
        browser.save_page("03-page-a1-moved")

        # STOP ALL: the button's click must reach the key space as a StopRequest.
        browser.page.get_by_role("button", name="STOP ALL").click()
        wait_until(lambda: any(s.source == "viewer" for s in stops), 10.0)
        with lock:
            ids = {s.stop_id for s in stops}
        assert len(ids) == 1 and len(next(iter(ids))) == 32  # one stop (repeated), a uuid4 hex
        assert harness.processes["viewer"].poll() is None, harness.log("viewer")
        # The agents latch the stop: the fleet panel says so, and the arms hold still.
        wait_until(
            lambda: browser.page.locator("#fleet-table").inner_text().count("STOPPED") == 3, 10.0
        )
        before = client.snapshot()
        time.sleep(1.0)
        after = client.snapshot()
        for arm in ("a1", "a2", "a3"):
            j0, j1 = before[arm][1], after[arm][1]
            assert j0 is not None and j1 is not None
            assert max(abs(a - b) for a, b in zip(j0.angles_deg, j1.angles_deg)) < 1.0, arm
        browser.save_page("04-page-after-stop")

        # The reset: both steps of the dialog, then the agents release the latch.
        browser.page.get_by_role("button", name="Reset stop…").click()
        browser.page.get_by_role("button", name="Reset every arm").click()
        wait_until(lambda: "STOPPED" not in browser.page.locator("#fleet-table").inner_text(), 10.0)
        subscriber.undeclare()
    assert browser.elsewhere(url.split("/?")[0]) == []  # nothing loaded from elsewhere

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    (ARTIFACTS / "browser-stats.json").write_text(
        json.dumps({"ws_frames_per_s_while_moving": round(rate, 1), "pixel_diffs": diffs})
    )


def test_the_fleet_panel_shows_a_killed_agent_as_offline(browser: Browser, tmp_path: Path) -> None:
    harness = fleet_harness_with_two_agents(tmp_path)
    try:
        url = start_viewer(harness)
        open_viewer(browser, url, ["a1", "a2"])
        stopped = time.monotonic()
        harness.stop("agent-a2")
        wait_until(lambda: browser.arm_online("a2") == "no", 20.0)
        print(f"a2 shown offline {time.monotonic() - stopped:.2f} s after SIGTERM to its agent")
        assert browser.arm_online("a1") == "yes"
        row = browser.page.locator("tr[data-arm='a2']").inner_text()
        assert "OFFLINE" in row
        # The event log says when it went (newest first, after both came online).
        kinds = browser.page.locator("#event-log tr[data-kind]")
        wait_until(lambda: kinds.first.get_attribute("data-kind") == "offline", 5.0)
        assert "a2" in kinds.first.inner_text() and "agent gone" in kinds.first.inner_text()
        time.sleep(0.5)
        browser.save_page("05-page-a2-offline")
        assert not_blank(browser.canvas("05-a2-offline"))
    finally:
        harness.close()


def fleet_harness_with_two_agents(tmp_path: Path) -> FleetHarness:
    """Two simulated arms, each with an agent of its own, so one can be killed alone."""
    (tmp_path / "two").mkdir()
    harness = FleetHarness(tmp_path / "two", arms=2)
    harness.start_router()
    harness.start_sim()
    harness.start_agent("a1", name="agent-a1")
    harness.start_agent("a2", name="agent-a2")
    client = harness.client()
    try:
        wait_until(lambda: harness.all_links_ok(client), 30.0)
    except AssertionError:
        harness.close()
        raise
    return harness


def evil_page(viewer_port: int) -> str:
    """A page of another origin that tries to open the viewer's WebSocket (as viser's client
    does) and writes the outcome into its title."""
    return f"""<!doctype html><title>trying</title><script>
    const socket = new WebSocket("ws://127.0.0.1:{viewer_port}/", ["viser-v{viser_version()}"]);
    socket.onopen = () => {{ document.title = "open"; }};
    socket.onclose = (event) => {{ document.title = "closed " + event.code; }};
    </script>"""


def viser_version() -> str:
    import viser

    return viser.__version__


def start_evil_page(harness: FleetHarness, viewer_port: int) -> str:
    """``python -m http.server`` on loopback serving ``evil.html``; returns its origin."""
    root = harness.tmp_path / "evil"
    root.mkdir()
    (root / "evil.html").write_text(evil_page(viewer_port), encoding="utf-8")
    port = free_port()
    argv = ["-m", "http.server", "--bind", "127.0.0.1", "--directory", str(root), str(port)]
    process = harness.start("evil-page", argv, inventory=False)

    def serving() -> bool:
        assert process.poll() is None, harness.log("evil-page")
        with socket.socket() as probe:
            return probe.connect_ex(("127.0.0.1", port)) == 0

    wait_until(serving, 10.0)
    return f"http://127.0.0.1:{port}"


def test_the_page_needs_the_printed_token_and_other_origins_are_refused(
    fleet_harness: FleetHarness, browser: Browser
) -> None:
    harness = fleet_harness
    harness.start_router()
    url = start_viewer(harness)  # the default principal 'viewer', an observer: read-only
    base = url.split("?")[0]
    port = int(base.rsplit(":", 1)[1].rstrip("/"))
    page = browser.page

    # Without the token (or with a wrong one): 403, a page saying what to open, no WebSocket.
    for target in (base, base + "?token=not-this-runs-token-0123"):
        response = page.goto(target)
        assert response is not None and response.status == 403, target
        assert "printed" in page.content()
        assert page.locator("canvas").count() == 0
    assert not [u for u in browser.requests if u.startswith("ws://")]
    browser.save_page("06-page-without-token")

    # With the printed URL: the viewer, over a WebSocket that carried the token (the cookie).
    page.goto(url)
    assert page.url == base
    page.locator("canvas").first.wait_for(timeout=30_000)
    # The GUI arrives over the WebSocket: its button shows the upgrade was accepted.
    page.get_by_role("button", name="STOP ALL").wait_for(timeout=15_000)
    page.get_by_text("Read-only viewer").wait_for(timeout=15_000)
    assert page.get_by_role("button", name="Reset stop…").count() == 0
    assert browser.elsewhere(base.rstrip("/")) == []
    browser.save_page("07-page-read-only")

    # A page of another origin in the same browser cannot open the viewer's WebSocket. It is
    # served from loopback by a real server (Chrome blocks a page it cannot place from reaching
    # loopback at all), so it is same-site with the viewer and its socket would carry the
    # cookie: the Origin check is what refuses it.
    evil = start_evil_page(harness, port)
    page.goto(f"{evil}/evil.html")
    wait_until(lambda: page.title() != "trying", 15.0)
    assert page.title().startswith("closed"), page.title()
    wait_until(lambda: f"Origin {evil!r} is not one of the viewer's" in harness.log("viewer"), 5)

    # A client with the token asks for viser's public share tunnel: refused, nothing opened.
    token = url.split("token=", 1)[1]
    connection = ws(port, base.rstrip("/"), query=f"?token={token}")
    assert isinstance(connection, ClientConnection)
    with connection:
        request = _messages.ShareUrlRequest().as_serializable_dict()
        connection.send(msgspec.msgpack.encode(request))
        wait_until(lambda: "public share URL" in harness.log("viewer"), 10.0)
    viewer = harness.processes["viewer"]
    assert viewer.poll() is None, harness.log("viewer")
    assert loopback_only(viewer.pid) == []
