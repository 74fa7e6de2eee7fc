"""The viewer process: a viser server, the fleet state (live from Zenoh, or a recording's
timeline), the scene and the panels.

Threads: Zenoh's (callbacks store the newest sample and return), viser's event loop and its
callback pool, ``viewer-render`` (ours: snapshot -> scene at ``rate_hz``, panels at
``panel_rate_hz``; in a replay it also moves the timeline), ``viewer-jog`` and ``viewer-stop``
(see viewer/commands.py). No lock is held across a viser update or a Zenoh put: the render
thread works on a snapshot copy. A replay opens no Zenoh session and builds no command control.

Access: the web server answers only requests carrying this run's token, and WebSockets only
from the viewer's own origins (fleet/web/access.py, installed by viewer/server.py). The viewer acts
as ``inventory.principal``; it is read-only unless that principal's role may command.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping, Sequence

import numpy as np
import viser

from fleet.devices import kind_of
from fleet.g1.config import G1Config
from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.record.layout import FleetLayout
from fleet.scene3d.g1_body import G1Placement
from fleet.scene3d.kinematics import ArmModel, load_urdf
from fleet.security.session import open_session
from fleet.web.access import AccessGuard, AccessPolicy, new_token, url_host
from fleet.wire import keys
from fleet.wire.session import close_bounded
from viewer.commands import Commander
from viewer.events import REFUSED
from viewer.g1_scene import G1Scene
from viewer.meshes import link_meshes
from viewer.panels import FleetPanels
from viewer.replay import ReplaySource, ReplayTimeline
from viewer.scene import FleetScene
from viewer.server import start_server
from viewer.state import ViewerFleet

log = logging.getLogger("viewer")

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
DEFAULT_RATE_HZ = 20.0
"""Scene updates per second at most; feedback is 10 Hz, so this never falls behind it."""
PANEL_RATE_HZ = 4.0


def shows_initial_camera(server: viser.ViserServer, camera: viser.CameraHandle) -> bool:
    """Whether ``camera``'s report shows the server's initial camera. viser 1.1.1's browser
    reports its own default pose first ((3, 3, 3) looking at the origin) and applies the
    initial camera later, in a React effect that also runs when the scene's up direction
    arrives; a fit sent before that effect was undone by it, so the first view sometimes
    kept the initial camera's assumed aspect and differed from "Fit view" (issue 26)."""
    initial = server.initial_camera
    return bool(
        np.allclose(camera.position, initial.position, atol=1e-3)
        and np.allclose(camera.look_at, initial.look_at, atol=1e-3)
    )


class Viewer:
    """The running viewer: of the live fleet of ``inventory``, or of a recording (``replay``).
    A context manager; ``close()`` is idempotent."""

    def __init__(
        self,
        inventory: Inventory | None = None,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        rate_hz: float = DEFAULT_RATE_HZ,
        token: str | None = None,
        allow_origins: Sequence[str] = (),
        read_only: bool = False,
        replay: ReplaySource | None = None,
    ) -> None:
        """``token``: the access token (a random one if None); ``allow_origins``: origins
        besides the viewer's own whose pages may open its WebSocket; ``read_only``: STOP ALL
        only (also the case when ``inventory.principal`` may not command); ``replay``: show
        this recording instead of the live fleet (``inventory`` is then not used). Raises
        ValueError for a malformed token or origin."""
        if (inventory is None) == (replay is None):
            raise ValueError("a viewer shows either a live inventory or a replay")
        self.inventory = inventory
        self.rate_hz = rate_hz
        self.access = AccessGuard(
            AccessPolicy(token=token or new_token(), host=host, allow_origins=tuple(allow_origins))
        )
        urdf = load_urdf()
        model = ArmModel.from_urdf(urdf)
        meshes = link_meshes(urdf, model.links)
        # Every thread and callback under one guard: a dead render or stop thread would leave a
        # viewer that shows a frozen fleet or a STOP ALL that confirms nothing; it exits instead.
        self.guard = ThreadGuard("viewer")
        self.failed = self.guard.failed
        fleet = inventory.fleet if inventory is not None else replay.layout.fleet  # type: ignore[union-attr]
        title = f"d1-fleet · {fleet}" + ("" if replay is None else " · replay")
        self.server = start_server(host, port, title, self.access)
        self.host = host
        self.port = self.server.get_port()  # viser silently takes the next free port
        self.session = None
        self.commander: Commander | None = None
        self.timeline: ReplayTimeline | None = None
        try:
            if replay is not None:
                self.timeline = ReplayTimeline(replay)
                self.state = self.timeline.state
                placements: FleetLayout | Inventory = replay.layout
                arms = tuple(replay.layout.arms)
                g1s: Mapping[str, G1Placement] = {
                    d: p for d, p in replay.layout.devices.items() if p.kind == keys.G1
                }
                device_kinds = {d: p.kind for d, p in replay.layout.devices.items()}
            else:
                assert inventory is not None
                self.session = open_session(inventory)
                devices = {
                    device: (kind_of(config), getattr(config, "mount", ""))
                    for device, config in inventory.devices.items()
                }
                self.state = ViewerFleet(
                    tuple(inventory.arms), inventory.fleet, self.session, devices=devices
                )
                self.commander = Commander(
                    inventory,
                    self.session,
                    notify=self._notify,
                    guard=self.guard,
                    read_only=read_only,
                )
                placements = inventory
                arms = tuple(inventory.arms)
                g1s = {d: c for d, c in inventory.devices.items() if isinstance(c, G1Config)}
                device_kinds = {d: kind_of(c).key for d, c in inventory.devices.items()}
        except BaseException:
            self.server.stop()
            raise
        self.read_only = self.commander is None or self.commander.read_only
        self.scene = FleetScene(self.server, placements.arms, model, meshes)
        # The G1s and devices, live from the inventory or laid out in the recording: the same
        # scenes and panels, fed by the same ViewerFleet.
        self.g1_scene: G1Scene | None = None
        if g1s:
            self.g1_scene = G1Scene(self.server, g1s, self.scene.base[:, :3, 3])
            self.scene.frame_also(self.g1_scene.frame_points)
        self.panels = FleetPanels(
            self.server,
            arms,
            self.commander,
            self.state.events,
            self.scene.fit,
            self.timeline,
            devices=device_kinds,
        )
        self._framed: set[int] = set()
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(lambda client: self._framed.discard(client.client_id))
        if self.session is not None:
            self.state.start(self.guard)
        self._closing = threading.Event()
        self._closed = False
        self._thread = self.guard.thread(self._render_loop, "viewer-render")
        self._thread.start()

    @property
    def base_url(self) -> str:
        """The viewer's own origin and page, without the token (it answers 403 there)."""
        return f"http://{url_host(self.host)}:{self.port}/"

    @property
    def url(self) -> str:
        """Where a browser finds the viewer: the page with this run's token."""
        return f"{self.base_url}?token={self.access.policy.token}"

    def _notify(self, title: str, body: str, is_error: bool) -> None:
        if is_error:
            self.state.events.add(REFUSED, None, f"{title}: {body}")
        self.panels.notify(title, body, is_error)

    def _on_connect(self, client: viser.ClientHandle) -> None:
        """Frame the fleet for this browser once it has told its canvas size (a camera
        message) and shows the initial camera: the initial camera assumed an aspect, this one
        knows it."""

        def first_camera(camera: viser.CameraHandle) -> None:
            if client.client_id in self._framed or not shows_initial_camera(self.server, camera):
                return
            self._framed.add(client.client_id)
            self.scene.fit(client)

        client.camera.on_update(first_camera)

    def _render_loop(self) -> None:
        period = 1.0 / self.rate_hz
        next_panels = 0.0
        next_tick = last = time.monotonic()
        while not self._closing.wait(max(0.0, next_tick - time.monotonic())):
            now = time.monotonic()
            # Fixed-rate ticks that skip, never catch up: a late tick is not followed by a
            # burst; the newest snapshot is all that is drawn.
            next_tick = max(next_tick + period, now)
            if self.timeline is not None:
                self.timeline.tick(now - last)
            last = now
            snapshot = self.state.snapshot()
            self.scene.render(snapshot)
            if self.g1_scene is not None:
                self.g1_scene.render(snapshot.devices)
            self.panels.record(snapshot, now)
            if now >= next_panels:
                next_panels = now + 1.0 / PANEL_RATE_HZ
                self.panels.update(snapshot)

    def close(self) -> None:
        """Shutdown order: stop drawing -> stop commanding (join) -> unsubscribe -> close the
        Zenoh session -> stop the web server."""
        if self._closed:
            return
        self._closed = True
        self._closing.set()
        self._thread.join(timeout=5.0)
        if self.commander is not None:
            self.commander.close()
        self.state.close()
        if self.session is not None:
            close_bounded(self.session, "session")
        self.server.stop()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
