"""The viewer process: a viser server, the fleet state from Zenoh, the scene and the panels.

Threads: Zenoh's (callbacks store the newest sample and return), viser's event loop and its
callback pool, ``viewer-render`` (ours: snapshot -> scene at ``rate_hz``, panels at
``panel_rate_hz``), ``viewer-jog`` and ``viewer-stop`` (see viewer/commands.py). No lock is held
across a viser update or a Zenoh put: the render thread works on a snapshot copy.
"""

from __future__ import annotations

import logging
import threading
import time

import viser

from fleet.guard import ThreadGuard
from fleet.inventory import Inventory
from fleet.security.session import open_session
from viewer.commands import Commander
from viewer.kinematics import ArmModel, load_urdf
from viewer.meshes import link_meshes
from viewer.panels import FleetPanels
from viewer.scene import FleetScene
from viewer.state import FleetState

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
    ) -> None:
        self.inventory = inventory
        self.rate_hz = rate_hz
        urdf = load_urdf()
        model = ArmModel.from_urdf(urdf)
        meshes = link_meshes(urdf, model.links)
        # Every thread and callback under one guard: a dead render or stop thread would leave a
        # viewer that shows a frozen fleet or a STOP ALL that confirms nothing; it exits instead.
        self.guard = ThreadGuard("viewer")
        self.failed = self.guard.failed
        self.session = open_session(inventory)
        self.server = viser.ViserServer(
            host=host, port=port, label=f"d1-fleet · {inventory.fleet}", verbose=False
        )
        self.host = host
        self.port = self.server.get_port()  # viser silently takes the next free port
        self.state = FleetState(inventory, self.session)
        self.commander = Commander(inventory, self.session, notify=self._notify, guard=self.guard)
        self.panels = FleetPanels(self.server, inventory, self.commander)
        self.scene = FleetScene(self.server, inventory, model, meshes)
        self.state.start(self.guard)
        self._closing = threading.Event()
        self._closed = False
        self.ticks = 0
        self._thread = self.guard.thread(self._render_loop, "viewer-render")
        self._thread.start()

    @property
    def url(self) -> str:
        """Where a browser finds the viewer."""
        return f"http://{self.host}:{self.port}"

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
            self.ticks += 1

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
