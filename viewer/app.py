"""The viewer process: a viser server, the fleet state from Zenoh, the scene and the panels.

Threads: Zenoh's (callbacks store the newest sample and return), viser's event loop and its
callback pool, ``viewer-render`` (ours: snapshot -> scene at ``rate_hz``, panels at
``panel_rate_hz``), ``viewer-jog`` and ``viewer-stop`` (see viewer/commands.py). No lock is held
across a viser update or a Zenoh put: the render thread works on a snapshot copy.

Access: the web server answers only requests carrying this run's token, and WebSockets only
from the viewer's own origins (viewer/access.py, installed by viewer/server.py). The viewer acts
as ``inventory.principal``; it is read-only unless that principal's role may command.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence

from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.security.session import open_session
from viewer.access import AccessGuard, AccessPolicy, new_token, url_host
from viewer.commands import Commander
from viewer.kinematics import ArmModel, load_urdf
from viewer.meshes import link_meshes
from viewer.panels import FleetPanels
from viewer.scene import FleetScene
from viewer.server import start_server
from viewer.state import ViewerFleet

log = logging.getLogger("viewer")

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
DEFAULT_RATE_HZ = 20.0
"""Scene updates per second at most; feedback is 10 Hz, so this never falls behind it."""
PANEL_RATE_HZ = 4.0


class Viewer:
    """The running viewer. A context manager; ``close()`` is idempotent."""

    def __init__(
        self,
        inventory: Inventory,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        rate_hz: float = DEFAULT_RATE_HZ,
        token: str | None = None,
        allow_origins: Sequence[str] = (),
        read_only: bool = False,
    ) -> None:
        """``token``: the access token (a random one if None); ``allow_origins``: origins
        besides the viewer's own whose pages may open its WebSocket; ``read_only``: STOP ALL
        only (also the case when ``inventory.principal`` may not command). Raises ValueError
        for a malformed token or origin."""
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
        self.server = start_server(host, port, f"d1-fleet · {inventory.fleet}", self.access)
        self.host = host
        self.port = self.server.get_port()  # viser silently takes the next free port
        try:
            self.session = open_session(inventory)
        except BaseException:
            self.server.stop()
            raise
        self.state = ViewerFleet(inventory, self.session)
        self.commander = Commander(
            inventory, self.session, notify=self._notify, guard=self.guard, read_only=read_only
        )
        self.read_only = self.commander.read_only
        self.panels = FleetPanels(self.server, inventory, self.commander)
        self.scene = FleetScene(self.server, inventory, model, meshes)
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
        self.panels.notify(title, body, is_error)

    def _render_loop(self) -> None:
        period = 1.0 / self.rate_hz
        next_panels = 0.0
        next_tick = time.monotonic()
        while not self._closing.wait(max(0.0, next_tick - time.monotonic())):
            now = time.monotonic()
            # Fixed-rate ticks that skip, never catch up: a late tick is not followed by a
            # burst; the newest snapshot is all that is drawn.
            next_tick = max(next_tick + period, now)
            snapshot = self.state.snapshot()
            self.scene.render(snapshot)
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
        self.commander.close()
        self.state.close()
        self.session.close()
        self.server.stop()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
