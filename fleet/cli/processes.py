"""Long-running processes: ``fleet router``, ``fleet sim`` and ``fleet demo``."""

from __future__ import annotations

import argparse
import ctypes
import logging
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import zenoh

from fleet.cli.demo_secure import secure_demo_inventory
from fleet.cli.screen import LogStream, Screen
from fleet.cli.supervise import Supervisor, stop_children
from fleet.client import FleetClient
from fleet.guard import EXIT_THREAD_FAILED, ThreadGuard
from fleet.inventory import Inventory
from fleet.observe import Observed, add_observe_options
from fleet.runtime import inventory_from_args, shutdown_event, wait_for
from fleet.security.session import router_config
from fleet.wire.session import close_bounded

log = logging.getLogger("fleet")
ACL_LOG = "zenoh::net::routing::interceptor::access_control"


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add the process commands to the ``fleet`` parser."""
    router = sub.add_parser("router", help="run a Zenoh router on the inventory's endpoints")
    add_common(router)
    router.add_argument(
        "--audit",
        action="store_true",
        help="log the access control's decisions (each 'is unauthorized to ...' names the "
        "principal, the message and the key), once per key and session",
    )
    router.add_argument(
        "--listen", action="append", metavar="EP", help="listen here instead (repeatable)"
    )
    router.add_argument(
        "--connect", action="append", metavar="EP", help="also join the router at EP (repeatable)"
    )
    add_observe_options(router)
    router.set_defaults(run=run_router)

    sim = sub.add_parser("sim", help="run the inventory's simulated arms on DDS")
    add_common(sim)
    sim.add_argument("--arm", action="append", help="only these arms (default: all simulated)")
    sim.add_argument("--seed", type=int, default=0, help="seed of the feedback jitter")
    sim.add_argument(
        "--no-zenoh",
        action="store_true",
        help="DDS only, no fault-injection queryable (a simulated arm alone on its own network)",
    )
    add_observe_options(sim)
    sim.set_defaults(run=run_sim)

    coordinator = sub.add_parser("coordinator", help="fleet state, heartbeat, multi-arm commands")
    add_common(coordinator)
    add_observe_options(coordinator)
    coordinator.set_defaults(run=run_coordinator)

    demo = sub.add_parser(
        "demo", help="router + simulated arms and devices + their agents, with status"
    )
    add_common(demo)
    demo.add_argument("--for-s", type=float, default=None, help="stop after this many seconds")
    demo.add_argument("--port", type=int, default=8080, help="viewer web port (default 8080)")
    demo.add_argument("--no-viewer", action="store_true", help="do not start the viewer")
    demo.add_argument(
        "--no-dance", action="store_true", help="do not play the default choreography"
    )
    demo.add_argument("--dance", default="choreo/demo.toml", help="the choreography the demo loops")
    demo.add_argument(
        "--foxglove",
        nargs="?",
        type=int,
        const=8765,
        default=None,
        metavar="PORT",
        help="also serve the fleet to Foxglove on ws://127.0.0.1:PORT (default 8765)",
    )
    demo.add_argument(
        "--ros2",
        action="store_true",
        help="also run `fleet ros2`: the fleet as ROS 2 nodes on rmw_zenoh's wire "
        "(docs/guide/ros2.md)",
    )
    demo.add_argument(
        "--secure",
        action="store_true",
        help="mutual TLS and the inventory's access control (certificates made for the run)",
    )
    demo.set_defaults(run=run_demo)


def run_router(args: argparse.Namespace) -> int:
    """Serve as the fleet's Zenoh router until SIGINT/SIGTERM."""
    inventory = inventory_from_args(args, "router")
    stop = shutdown_event()
    if args.audit:
        zenoh.init_log_from_env_or(f"{ACL_LOG}=trace,error")
    elif os.environ.get("RUST_LOG"):
        zenoh.init_log_from_env_or("error")
    listen, connect = args.listen or inventory.endpoints, args.connect or []
    busy = [e for e in listen if not _port_free(e)]
    if busy:
        print(busy_message("fleet router", busy), file=sys.stderr)
        return 3
    try:
        session = zenoh.open(router_config(inventory, listen, connect))
    except zenoh.ZError as exc:  # taken between the check and the bind, or another reason
        if "in use" not in str(exc):
            raise
        print(busy_message("fleet router", listen), file=sys.stderr)
        return 3
    joined = f", joined to {', '.join(connect)}" if connect else ""
    log.info("Zenoh router listening on %s%s", ", ".join(listen), joined)
    try:
        with Observed(session, inventory, "router", args.metrics_port):
            wait_for(stop)
    finally:
        close_bounded(session, "router session")
    return 0


def run_sim(args: argparse.Namespace) -> int:
    """Run simulated arms and devices (grippers, G1s) until SIGINT/SIGTERM."""
    from fleet.sim.devices import SimulatedDevices
    from fleet.sim.metrics import sim_collectors
    from fleet.sim.node import SimulatedArms  # DDS is only loaded by the commands that use it

    inventory = inventory_from_args(args, "sim")
    arms = args.arm or [a.id for a in inventory.arms.values() if a.simulated]
    devices = [] if args.arm else [d.id for d in inventory.devices.values() if d.simulated]
    if not arms and not devices:
        print("fleet sim: the inventory marks no arm or device as simulated", file=sys.stderr)
        return 2
    stop = shutdown_event()
    with ExitStack() as stack:
        sim = stack.enter_context(SimulatedArms(inventory, arms, seed=args.seed)) if arms else None
        guards = []
        if sim is not None:
            sim.start(with_zenoh=not args.no_zenoh)
            guards.append(sim.guard)
            log.info(
                "simulating arms %s on DDS domain %d",
                ", ".join(arms),
                inventory.domain_of(inventory.arm(arms[0])),
            )
            arm_sim = sim
            stack.enter_context(
                Observed(
                    sim.session,
                    inventory,
                    "sim",
                    args.metrics_port,
                    arms,
                    lambda: sim_collectors(arm_sim),
                )
            )
        if devices:
            participant = sim.participant if sim is not None else None
            device_sim = stack.enter_context(SimulatedDevices(inventory, devices, participant))
            device_sim.start()
            guards.append(device_sim.guard)
            log.info("simulating devices %s", ", ".join(devices))
        failed = wait_for(stop, guards[0].failed if len(guards) == 1 else _any_failed(guards))
    failure = next((g.failure for g in guards if g.failed.is_set()), None)
    if failed or failure:
        log.error("%s: the simulator stopped; restart it", failure)
        return EXIT_THREAD_FAILED
    return 0


def _any_failed(guards: list[ThreadGuard]) -> threading.Event:
    """An Event set once any of ``guards`` failed (polled by a small daemon thread)."""
    event = threading.Event()

    def watch() -> None:
        while not event.is_set():
            if any(g.failed.wait(0.1) for g in guards):
                event.set()

    threading.Thread(target=watch, name="sim-failed", daemon=True).start()
    return event


def run_coordinator(args: argparse.Namespace) -> int:
    """Run the coordinator until SIGINT/SIGTERM."""
    from fleet.coordinator.metrics import coordinator_collectors
    from fleet.coordinator.service import Coordinator

    inventory = inventory_from_args(args, "coordinator")
    stop = shutdown_event()
    with Coordinator(inventory) as coordinator:
        coordinator.start()
        with Observed(
            coordinator.session,
            inventory,
            "coordinator",
            args.metrics_port,
            collectors=lambda: coordinator_collectors(coordinator),
        ):
            failed = wait_for(stop, coordinator.failed)
    if failed:
        log.error(
            "%s: the heartbeat stopped (agents hold the arms it commanded); restart it",
            coordinator.guard.failure,
        )
        return EXIT_THREAD_FAILED
    return 0


# ----------------------------------------------------------------------------- demo


def busy_message(command: str, endpoints: list[str]) -> str:
    """One line for a port that is taken (no traceback): what, and what to do."""
    return (
        f"{command}: {', '.join(endpoints)} is in use (another router or demo?); "
        "stop it or pass --endpoint tcp/127.0.0.1:<port>"
    )


def _port_free(endpoint: str) -> bool:
    """True when ``endpoint``'s (``tcp/host:port``) port can be listened on now; an endpoint
    of another shape (no port) is not checked here."""
    host, _, port = endpoint.split("/", 1)[-1].rpartition(":")
    if not port.isdigit():
        return True
    host = host.strip("[]")
    with socket.socket() as probe:
        # As the router binds: a port whose last connections linger in TIME-WAIT (the previous
        # demo's) is free to listen on, and must not read as "in use" for a minute.
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, int(port)))
        except OSError:
            return False
    return True


PR_SET_PDEATHSIG = 1


def _owned_by_demo(parent: int) -> Callable[[], None]:
    """For a child, run between fork and exec. It gets a process group of its own: a Ctrl-C in
    the demo's terminal (SIGINT to the terminal's foreground group) reaches the demo alone, which
    stops each child by PID; before, every child got it too, most in the middle of their imports
    (a traceback each). And the kernel sends it SIGTERM when the demo dies, however it dies (a
    SIGKILL cannot be handled, so the demo could not stop its children)."""

    def arrange() -> None:
        os.setpgid(0, 0)
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:  # the demo died before the line above: nobody will stop us
            os._exit(1)

    return arrange


def _spawn(argv: list[str], **options: Any) -> subprocess.Popen[Any]:
    return subprocess.Popen(
        [sys.executable, *argv], preexec_fn=_owned_by_demo(os.getpid()), **options
    )


class _Children:
    """Spawns the demo's children with their output (stdout and stderr, line by line) piped
    through the demo's screen, above the status block; remembers the viewer's URL line."""

    def __init__(self, screen: Screen) -> None:
        self.screen = screen
        self.urls: list[str] = []

    def spawn(self, argv: list[str], **_options: Any) -> subprocess.Popen[Any]:
        process = _spawn(
            argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace"
        )
        self.screen.follow(process, self._look_for_url)
        return process

    def _look_for_url(self, line: str) -> None:
        # The viewer's own line (viser prints its token-less address first).
        if "d1-fleet viewer: http://" in line:
            self.urls.append(line.split("d1-fleet viewer: ", 1)[1].split()[0])


def _common_argv(args: argparse.Namespace, inventory: Inventory) -> list[str]:
    argv = ["--inventory", args.inventory, "--domain", str(inventory.domain_id)]
    for endpoint in inventory.endpoints:
        argv += ["--endpoint", endpoint]
    # The children append to the demo's --log-file too (one file, each line with its role).
    if args.log_file is not None:
        argv += ["--log-file", args.log_file]
    return argv + ["--log-level", "WARNING", "--log-format", args.log_format]


DANCE = "dance"
"""The demo's child that plays the choreography: not supervised (a stop ends it, and the fleet
is fine without it; the operator starts it again)."""
PATIENCE_S = 8.0
"""How long the demo's children have, in all, to shut down cleanly (an agent holds its robots
first) after the demo's SIGTERM; then SIGKILL. A G1's agent releases its arms before it exits,
a weight ramp of ``arm_release_s`` (3-5 s): at 5 s a loaded host's agent was killed mid-ramp
(the weight left between 1 and 0). The agent's own shutdown bound is 8 s too."""
PATIENCE_STARTING_S = 1.5
"""The same when the demo is stopped while it starts them: a child may be mid start-up (a DDS
participant, a session to a router) with its handler set, and nothing is commanded yet."""


def run_demo(args: argparse.Namespace) -> int:
    """Start the demo fleet as child processes, print a status line per arm, stop them all."""
    # First: a Ctrl-C from here on stops the demo cleanly, even while it writes certificates.
    stop = shutdown_event(bound_s=None)  # its children are bounded (supervise.stop_children)
    inventory = inventory_from_args(args)
    if args.domain is None:
        # A domain of its own, so two demos (or a demo and a test run) never cross-talk.
        inventory = inventory.with_domain(random.randint(1, 99))
    # A directory of the run's own: certificates (--secure), and the agents' latched stops (the
    # simulated arms start over at every demo, so must their latches).
    workdir = tempfile.TemporaryDirectory(prefix="d1-fleet-demo-")
    os.environ["D1_FLEET_STATE_DIR"] = str(Path(workdir.name) / "state")
    if args.secure:
        inventory = secure_demo_inventory(args, inventory, Path(workdir.name))
    try:
        return 0 if stop.is_set() else _run_demo(args, inventory, stop)
    finally:
        workdir.cleanup()


def _demo_children(args: argparse.Namespace, inventory: Inventory) -> list[tuple[str, list[str]]]:
    """(name, argv) of the demo's children in start order, the router first."""
    common = _common_argv(args, inventory)
    out = [("router", ["-m", "fleet.cli.main", "router", *common])]
    if any(a.simulated for a in inventory.arms.values()):
        out.append(("simulator", ["-m", "fleet.cli.main", "sim", *common]))
    # One agent process per network card and agent identity: an arm and the devices mounted
    # on it share one (their agent is the arm's by default).
    for label, argv in agent_processes(inventory):
        out.append((f"agent of {label}", ["-m", "edge_agent", *argv, *common]))
    out.append(("coordinator", ["-m", "fleet.cli.main", "coordinator", *common]))
    if not args.no_dance:
        # Loops until a stop, which ends it: a reset permits motion, never restarts it (the
        # operator does, with the command printed by _intro).
        dance = ["play", args.dance, "--loops", "0", "--quiet", "--ready-s", "30"]
        out.append((DANCE, ["-m", "fleet.cli.main", *dance, *common]))
    if args.foxglove is not None:
        # The token reaches the child in its environment (not its argv: the process list
        # shows that to every user); _intro prints the URL with it.
        from fleet.web.access import FOXGLOVE_TOKEN_ENV as TOKEN_ENV
        from fleet.web.access import new_token

        os.environ.setdefault(TOKEN_ENV, new_token())
        fox = ["-m", "fleet.cli.main", "foxglove", "--port", str(args.foxglove), *common]
        out.append(("foxglove", fox))
    if args.ros2:
        out.append(("ros2", ["-m", "fleet.cli.main", "ros2", *common]))
    if not args.no_viewer:
        # The person running the demo operates their own simulated fleet: the viewer acts
        # as 'operator' (reset and jog), not as the read-only default principal 'viewer'.
        viewer = ["-m", "fleet.cli.main", "viewer", "--port", str(args.port)]
        out.append(("viewer", [*viewer, "--principal", "operator", *common]))
    return out


def _run_demo(args: argparse.Namespace, inventory: Inventory, stop: threading.Event) -> int:
    busy = [e for e in inventory.endpoints if not _port_free(e)]
    if busy:
        print(busy_message("fleet demo", busy), file=sys.stderr)
        return 3
    screen = Screen(sys.stdout)
    spawner = _Children(screen)
    supervisor = Supervisor(spawner.spawn, say=screen.log)
    unsupervised: list[subprocess.Popen[Any]] = []
    started: dict[str, subprocess.Popen[Any]] = {}  # the first process of each
    gave_up = None
    running = False
    try:
        for name, argv in _demo_children(args, inventory):
            if stop.is_set():  # Ctrl-C while starting: start no more, stop those started
                break
            if name == DANCE:
                started[name] = spawner.spawn(argv)
                unsupervised.append(started[name])
            else:
                started[name] = supervisor.start(name, argv)
            if name == "router":
                stop.wait(0.5)  # let the router bind before the others connect (they retry)
        url = "not started (--no-viewer)"
        if "viewer" in started and not stop.is_set():
            # (A restarted viewer prints its new URL on the demo's own output.)
            url = _viewer_url(started["viewer"], spawner.urls, stop)
        if not stop.is_set():
            running = True
            for line in _intro(args, inventory, url):
                screen.log(line)
            gave_up = _print_status_until(
                stop, inventory, args.for_s, supervisor, screen, unsupervised
            )
    finally:
        patience_s = PATIENCE_S if running else PATIENCE_STARTING_S
        stop_children(_stop_stages({**supervisor.current(), **started}), patience_s)
    if gave_up is not None:
        print(f"fleet demo: {gave_up}", file=sys.stderr)
        return 1
    return 0


COMMANDERS = (DANCE, "viewer", "foxglove", "ros2")
"""The demo's children that command robots or serve people (the player, the viewer's jog...)."""


def _stop_stages(
    children: dict[str, subprocess.Popen[Any]],
) -> list[list[subprocess.Popen[Any]]]:
    """The order the demo stops its children in: the commanders (what they moved is held while
    its agent still listens), then the fleet's processes, the router last."""
    commanders = [p for name, p in children.items() if name in COMMANDERS]
    fleet = [p for name, p in children.items() if name not in (*COMMANDERS, "router")]
    return [commanders, fleet, [children["router"]] if "router" in children else []]


def fleet_command() -> str:
    """How to type ``fleet`` in this shell: ``fleet`` when it is on PATH (the same one),
    else the path of the one beside this Python (``.venv/bin/fleet`` after ``make demo``)."""
    beside = Path(sys.executable).parent / "fleet"
    found = shutil.which("fleet")
    if not beside.exists() or (found is not None and Path(found).resolve() == beside.resolve()):
        return "fleet"
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


def _intro(args: argparse.Namespace, inventory: Inventory, url: str) -> list[str]:
    """What the demo prints once, above its status block: where things are, how to use them."""
    fleet = fleet_command()
    # The CLI needs the demo's inventory when it is not the one the CLI finds by default (the
    # secure demo's temporary copy names the certificates), and its router's endpoint.
    common = f"--inventory {args.inventory} --endpoint {inventory.endpoints[0]}"
    lines = [
        f"d1-fleet demo: fleet {inventory.fleet!r}, DDS domain {inventory.domain_id}, "
        f"Zenoh router on {', '.join(inventory.endpoints)}",
        f"viewer: {url}",
    ]
    if args.foxglove is not None:
        from fleet.web.access import FOXGLOVE_TOKEN_ENV as TOKEN_ENV

        token = os.environ.get(TOKEN_ENV, "")
        lines.append(
            f"foxglove: ws://127.0.0.1:{args.foxglove}/?token={token} "
            "(Open connection in Foxglove, with the token)"
        )
    if args.ros2:
        lines.append(
            f"ros2: ROS_DOMAIN_ID={inventory.ros2.domain_id}, stop service "
            f"/{inventory.fleet}/estop (rmw_zenoh, router {inventory.endpoints[0]})"
        )
    if args.secure:
        lines.append(
            f"inventory with the certificates (removed when the demo ends): {args.inventory}"
        )
    lines.append(f"try: {fleet} status {common}")
    if not args.no_dance:
        lines.append(
            f"a stop ends the dance; after the reset, start it again with: {fleet} play "
            f"{args.dance} --loops 0 {common}"
        )
    lines.append("Ctrl-C stops the demo")
    return lines


def _viewer_url(
    viewer: subprocess.Popen[Any], urls: list[str], stop: threading.Event, timeout_s: float = 30.0
) -> str:
    """The URL the viewer prints once it serves (it may move to another port if busy)."""
    deadline = time.monotonic() + timeout_s
    while not urls and time.monotonic() < deadline and viewer.poll() is None:
        if stop.wait(0.1):
            break
    return urls[0] if urls else "did not start (see its log above)"


def _print_status_until(
    stop: threading.Event,
    inventory: Inventory,
    for_s: float | None,
    supervisor: Supervisor,
    screen: Screen,
    children: list[subprocess.Popen[Any]],
) -> str | None:
    """Draw the status block once a second (log lines above it) and keep the children running;
    why the demo gave up on a child, or None."""
    from fleet.cli.status import device_lines, status_lines

    deadline = None if for_s is None else time.monotonic() + for_s
    # The demo's own logging goes above the block too (its handler writes to sys.stderr).
    stderr, sys.stderr = sys.stderr, LogStream(screen)
    try:
        with FleetClient(inventory) as client:
            while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
                gave_up = supervisor.check(time.monotonic())
                if gave_up is not None:
                    return gave_up
                for child in children:
                    child.poll()  # reap a player that ended (a stop ends the dance): no zombie
                snapshot, alive = client.snapshot(wait_s=1.0), client.agents_alive()
                state = client.fleet_state(wait_s=0.3)
                lines = status_lines(inventory, snapshot, alive, state, screen.width())
                lines += device_lines(inventory, client.device_snapshot(wait_s=0.3))
                screen.draw(lines)
                stop.wait(1.0)
    finally:
        sys.stderr = stderr
    return None


def agent_processes(inventory: Inventory) -> list[tuple[str, list[str]]]:
    """(label, edge-agent arguments) of the agent processes serving ``inventory``: one per
    network card and agent principal (one process has one identity), each naming its robots."""
    groups: dict[tuple[str, str], list[str]] = {}
    for unit in [*inventory.arms.values(), *inventory.devices.values()]:
        groups.setdefault((unit.interface, unit.agent), []).append(unit.id)
    out = []
    for (_card, principal), units in groups.items():
        argv = ["--principal", principal]
        for unit in units:
            argv += ["--arm" if unit in inventory.arms else "--device", unit]
        out.append((", ".join(units), argv))
    return out
