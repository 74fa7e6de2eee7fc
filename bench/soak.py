"""Soak: the demo fleet for a long time under link flaps, agent restarts, viewer reconnects and
fleet stops, with memory, CPU and stop times recorded (``make soak DURATION=30m``).

    python -m bench.soak --duration 30m [--out artifacts/soak]

The fleet is the demo's (``fleet demo``): a router, ``fleet sim`` with three arms, one agent per
arm, the coordinator, the viewer (headless: nobody opens it but the soak's own clients) and
``fleet play choreo/demo.toml --loops 0 --again`` dancing; on loopback, with a Zenoh port and a
DDS domain of its own (``testkit/harness.py``). Every process is started and stopped by PID.

Events, one every ``period`` seconds (30 s for runs of 30 min and more), in the cycle
``CYCLE``: a **fleet stop** (``FleetClient.estop``: every arm must acknowledge and be seen
still, then checked still from the soak's own joints samples, then ``reset``); a **link
flap** (the simulated arm drops its feedback for ``FLAP_S`` via ``arm/<arm>/sim/fault``, the
agent must report the link not ok, then ok again once it is back); an **agent restart** (SIGTERM
or SIGKILL, alternately, to the agent of a2 or a3; the new one must serve the arm again); a
**viewer reconnect** (the page over HTTP, then ``VIEWER_CLIENTS`` WebSocket sessions that must
each receive scene messages). The agent of a1 is never restarted: it is the agent whose memory
is measured over the whole run.

A sampler thread reads RSS and CPU time of every process from /proc every ``SAMPLE_S`` and the
agents' and coordinator's ``diag`` counters (queue overflows, busy answers, requests in
flight). ``bench/soak_report.py`` turns the record into ``report.md``, ``soak.png`` and
``soak.json`` under the output directory and checks the goals (exit code 1 if one is missed).
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import zenoh
from websockets.sync.client import connect as ws_connect

from bench.proc import REPO, Worker, cpu_s, rss_mb
from bench.soak_report import SoakRecord, write_report
from fleet.client import FleetClient
from fleet.guard import ThreadGuard
from fleet.inventory import load_inventory
from fleet.sim.faults import FaultReply
from fleet.wire import keys, payloads
from fleet.wire.messages import StopAck
from testkit.harness import claim_domain, free_port, inventory_text

ARMS = ("a1", "a2", "a3")
SAMPLE_S = 5.0
FLAP_S = 3.0
VIEWER_CLIENTS = 3
CYCLE = ("stop", "flap", "stop", "restart", "stop", "viewer")
"""Half the events are fleet stops: the check that matters most gets the most samples."""
RESTARTED = ("a2", "a3")
READY_TIMEOUT_S = 60.0
STILL_DEG = 0.5
"""Largest joint motion over 0.5 s that the soak's own check accepts as "still" after a stop."""
FLEET = "soak"


def parse_duration(text: str) -> float:
    """``90s``, ``5m``, ``1h``, ``1.5h`` or plain seconds -> seconds."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smh]?)\s*", text)
    if match is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration like 90s, 5m or 1h")
    value = float(match.group(1)) * {"": 1, "s": 1, "m": 60, "h": 3600}[match.group(2)]
    if value < 30:
        raise argparse.ArgumentTypeError("a soak needs at least 30 s")
    return value


@dataclass
class Fleet:
    """The soak's processes, by role, each restartable; stopped by PID."""

    out: Path
    port: int = field(default_factory=free_port)
    viewer_port: int = field(default_factory=free_port)
    workers: dict[str, Worker] = field(default_factory=dict)
    incarnation: dict[str, int] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self.domain, self._domain_lock = claim_domain()
        self.logs = self.out / "logs"
        shutil.rmtree(self.logs, ignore_errors=True)
        self.logs.mkdir(parents=True)
        self.inventory_path = self.out / "inventory.toml"
        text = inventory_text(FLEET, self.port, self.domain, arms=len(ARMS))
        self.inventory_path.write_text(text, encoding="utf-8")
        self.inventory = load_inventory(self.inventory_path)

    def argv(self, role: str) -> list[str]:
        """The command line of ``role`` (without the interpreter)."""
        common = ["--inventory", str(self.inventory_path), "--log-level", "WARNING"]
        cli = ["-m", "fleet.cli.main"]
        if role.startswith("agent-"):
            return ["-m", "edge_agent", "--arm", role.removeprefix("agent-"), *common]
        if role == "viewer":
            return [*cli, "viewer", "--port", str(self.viewer_port), *common]
        if role == "player":
            demo = str(REPO / "choreo" / "demo.toml")
            dance = ["play", demo, "--loops", "0", "--quiet", "--ready-s", "30", "--again"]
            return [*cli, *dance, *common]
        return [*cli, role, *common]  # router, sim, coordinator

    def start(self, role: str) -> Worker:
        """Start (or restart) ``role``; its log is ``logs/<role>.<incarnation>.log``."""
        with self.lock:
            n = self.incarnation.get(role, 0) + 1
            self.incarnation[role] = n
            worker = Worker(f"{role}.{n}", self.argv(role), self.logs, piped=False)
            self.workers[role] = worker
        return worker

    def pids(self) -> dict[str, Worker]:
        """The current worker of every role (a copy)."""
        with self.lock:
            return dict(self.workers)

    def wait_port(self, port: int, timeout_s: float) -> bool:
        """True once 127.0.0.1:``port`` accepts connections (bounded)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with socket.socket() as probe:
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    return True
            time.sleep(0.1)
        return False

    def close(self) -> None:
        """Stop every process by PID (the player and viewer first, the router last)."""
        order = ["player", "viewer", "coordinator", *(f"agent-{a}" for a in ARMS), "sim", "router"]
        for role in order:
            worker = self.workers.get(role)
            if worker is not None:
                worker.stop()
        self._domain_lock.close()


class Soak:
    """One soak run: the fleet, the sampler thread, the events, the record."""

    def __init__(self, duration_s: float, out: Path) -> None:
        self.duration_s = duration_s
        self.period_s = min(30.0, max(5.0, duration_s / 60.0))
        self.out = out
        self.fleet = Fleet(out)
        self.guard = ThreadGuard("soak")
        self.record = SoakRecord(duration_s=duration_s, period_s=self.period_s)
        self.record.load_start = os.getloadavg()
        self._stop_sampling = threading.Event()
        self._restarting: set[str] = set()
        self._diag_lock = threading.Lock()
        self._diag: dict[str, dict[str, Any]] = {}
        self._t0 = time.monotonic()
        self.client: FleetClient | None = None
        self._subs: list[Any] = []

    # ------------------------------------------------------------------ start-up

    def start(self) -> FleetClient:
        """Every process, then a client once every arm's link is ok (bounded)."""
        self.fleet.start("router")
        if not self.fleet.wait_port(self.fleet.port, 20.0):
            raise RuntimeError(f"router did not listen\n{self.fleet.workers['router'].log_tail()}")
        for role in ("sim", *(f"agent-{a}" for a in ARMS), "coordinator", "viewer", "player"):
            self.fleet.start(role)
        client = FleetClient(self.fleet.inventory)
        self.client = client
        space = keys.KeySpace(FLEET)
        self._subs = [
            client.session.declare_subscriber(
                space.all_arms(keys.DIAG), self.guard.wrap(self._on_diag, "soak-diag")
            ),
            client.session.declare_subscriber(
                space.coordinator_diag, self.guard.wrap(self._on_diag, "soak-diag")
            ),
        ]
        if not self._wait_links(list(ARMS), READY_TIMEOUT_S):
            raise RuntimeError("the fleet did not come up (links not ok)")
        if not self.fleet.wait_port(self.fleet.viewer_port, READY_TIMEOUT_S):
            raise RuntimeError(f"viewer did not serve\n{self.fleet.workers['viewer'].log_tail()}")
        self._t0 = time.monotonic()
        return client

    def _on_diag(self, sample: zenoh.Sample) -> None:
        """Zenoh callback: decode and store the newest diag (nothing else happens here)."""
        key = str(sample.key_expr)
        data = sample.payload.to_bytes()
        try:
            if key.endswith(keys.COORDINATOR_DIAG):
                diag: Any = payloads.decode(keys.COORDINATOR_DIAG, data)
                name = "coordinator"
            else:
                diag = payloads.decode(keys.DIAG, data)
                name = "agent-" + keys.KeySpace(FLEET).parse_arm_key(key).arm
        except (payloads.PayloadError, keys.KeyError_):
            return
        fields = {f: getattr(diag, f) for f in diag.__struct_fields__}
        with self._diag_lock:
            self._diag[name] = {k: v for k, v in fields.items() if isinstance(v, (int, float))}

    # ------------------------------------------------------------------ sampling

    def now(self) -> float:
        """Seconds since the soak's clock started (after start-up)."""
        return time.monotonic() - self._t0

    def _sample_loop(self) -> None:
        last: dict[int, tuple[float, float]] = {}
        while not self._stop_sampling.wait(SAMPLE_S):
            self._sample_once(last)

    def _sample_once(self, last: dict[int, tuple[float, float]]) -> None:
        t = self.now()
        for role, worker in self.fleet.pids().items():
            if not worker.alive():
                continue  # booked and restarted by the main thread (_recover_dead)
            try:
                rss, cpu = rss_mb(worker.pid), cpu_s(worker.pid)
            except (FileNotFoundError, ProcessLookupError):
                continue  # exited between the check and the read
            previous = last.get(worker.pid)
            percent = None if previous is None else 100.0 * (cpu - previous[1]) / (t - previous[0])
            last[worker.pid] = (t, cpu)
            self.record.add_sample(role, self.fleet.incarnation[role], t, rss, percent)
        with self._diag_lock:
            diag = {name: dict(values) for name, values in self._diag.items()}
        self.record.diag.append((round(t, 1), diag))
        self.record.load.append((round(t, 1), os.getloadavg()[0]))

    # ------------------------------------------------------------------ events

    def run(self) -> None:
        """Sample and fire events until the duration is over, then one last stop."""
        sampler = self.guard.thread(self._sample_loop, "soak-sampler")
        sampler.start()
        index, restarts, flaps = 0, 0, 0
        next_event = self.period_s
        try:
            while self.now() < self.duration_s and not self.guard.failed.is_set():
                self._recover_dead()
                if self.now() < next_event:
                    time.sleep(min(1.0, next_event - self.now()))
                    continue
                kind = CYCLE[index % len(CYCLE)]
                index += 1
                if kind == "stop":
                    self.event("stop", "all", self.fleet_stop)
                elif kind == "flap":
                    arm = ARMS[flaps % len(ARMS)]
                    flaps += 1
                    self.event("flap", arm, lambda a=arm: self.link_flap(a))
                elif kind == "restart":
                    arm = RESTARTED[restarts % len(RESTARTED)]
                    sig = signal.SIGTERM if restarts % 4 in (0, 3) else signal.SIGKILL
                    restarts += 1
                    self.event(
                        f"restart ({sig.name})", arm, lambda a=arm, s=sig: self.restart_agent(a, s)
                    )
                else:
                    self.event("viewer", "viewer", self.viewer_reconnect)
                next_event = max(next_event + self.period_s, self.now())
            self.event("stop", "all", self.fleet_stop)  # the last one, after the last sample
        finally:
            self._stop_sampling.set()
            sampler.join(timeout=SAMPLE_S * 3)
        if self.guard.failed.is_set():
            raise RuntimeError(f"the soak's own thread failed: {self.guard.failure}")

    def event(self, kind: str, target: str, action: Callable[[], tuple[bool, str]]) -> None:
        """Run one event and book its outcome."""
        started = self.now()
        ok, detail = action()
        took = self.now() - started
        self.record.events.append(
            {"t": round(started, 1), "kind": kind, "target": target, "ok": ok, "detail": detail,
             "s": round(took, 2)}
        )  # fmt: skip
        mark = "ok " if ok else "FAIL"
        print(f"[{started:7.1f} s] {mark} {kind} {target}: {detail} ({took:.1f} s)", flush=True)

    def _recover_dead(self) -> None:
        """A process that died outside a restart event is booked (``record.died``) and
        restarted, so the soak goes on and the report shows it."""
        for role, worker in self.fleet.pids().items():
            if not worker.alive() and role not in self._restarting:
                code = worker.process.returncode
                self.record.died.append((round(self.now(), 1), role, code))
                worker.stop()
                self.fleet.start(role)
                print(f"[{self.now():7.1f} s] {role} exited with {code}; restarted", flush=True)

    def _client(self) -> FleetClient:
        assert self.client is not None, "start() first"
        return self.client

    def _links(self, arms: list[str]) -> dict[str, str | None]:
        snapshot = self._client().snapshot(arms, wait_s=0.6)
        return {a: (s.link if s is not None else None) for a, (s, _j) in snapshot.items()}

    def _wait_links(self, arms: list[str], timeout_s: float, ok: bool = True) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            links = self._links(arms)
            if all((link == "ok") == ok for link in links.values()):
                return True
        return False

    def _ready(self) -> bool:
        """Every agent alive and every link ok (bounded)."""
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            if self._client().agents_alive() >= set(ARMS) and self._wait_links(list(ARMS), 2.0):
                return True
        return False

    def fleet_stop(self) -> tuple[bool, str]:
        """Stop every arm, require every ack and standstill, check still ourselves, reset."""
        client = self._client()
        ready = self._ready()
        moving = self._motion_deg(0.3)  # was the dance on when the stop came?
        request = client.stop_request(reason="soak", source="soak")
        started = time.monotonic()
        acks = client.estop(request=request, timeout_s=5.0, wait_still=True)
        call_ms = (time.monotonic() - started) * 1000.0
        confirmed = all(a is not None and a.still_ns is not None for a in acks.values())
        motion = self._motion_deg(0.5)
        still = motion is not None and motion <= STILL_DEG
        client.reset(source="soak")
        released = self._wait_released(10.0)
        self.record.add_stop(self.now(), request.stamp_ns, acks, call_ms, confirmed and still)
        self.record.stops[-1]["moving_deg"] = moving
        missing = [a for a, ack in acks.items() if ack is None or ack.still_ns is None]
        detail = (
            f"moving {'n/a' if moving is None else f'{moving:.1f}'} deg before; "
            f"{_stop_text(request.stamp_ns, acks)}; call {call_ms:.0f} ms; motion after "
            f"{'n/a' if motion is None else f'{motion:.2f}'} deg; "
            f"{'released' if released else 'NOT released'}"
            + ("" if ready else "; fleet was not ready before the stop")
            + (f"; unconfirmed: {', '.join(missing)}" if missing else "")
        )
        return confirmed and still and released, detail

    def _motion_deg(self, over_s: float) -> float | None:
        """The largest joint motion of any arm over ``over_s`` seconds (from joints samples)."""
        client = self._client()
        before = client.snapshot(list(ARMS), wait_s=1.0)
        time.sleep(over_s)
        after = client.snapshot(list(ARMS), wait_s=1.0)
        worst = 0.0
        for arm in ARMS:
            a, b = before[arm][1], after[arm][1]
            if a is None or b is None:
                return None
            worst = max(worst, *(abs(x - y) for x, y in zip(a.angles_deg, b.angles_deg)))
        return worst

    def _wait_released(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            snapshot = self._client().snapshot(list(ARMS), wait_s=0.6)
            if all(s is not None and not s.estopped for s, _j in snapshot.values()):
                return True
        return False

    def link_flap(self, arm: str) -> tuple[bool, str]:
        """Feedback off for FLAP_S: the link must go not-ok, then come back ok."""
        if not self._fault(arm, b'{"op":"drop_feedback","on":true}'):
            return False, "the simulator refused drop_feedback"
        started = time.monotonic()
        seen_down = self._wait_links([arm], FLAP_S, ok=False)
        time.sleep(max(0.0, FLAP_S - (time.monotonic() - started)))
        if not self._fault(arm, b'{"op":"drop_feedback","on":false}'):
            return False, "the simulator refused to end drop_feedback"
        back = time.monotonic()
        up = self._wait_links([arm], 15.0)
        recovered_s = time.monotonic() - back
        detail = (
            f"link {'went' if seen_down else 'did NOT go'} down; back ok in {recovered_s:.1f} s"
        )
        return seen_down and up, detail

    def _fault(self, arm: str, payload: bytes) -> bool:
        key = self._client().keys.arm(arm, keys.SIM_FAULT)
        for reply in self._client().session.get(key, payload=payload, timeout=5.0):
            if reply.ok is not None:
                try:
                    return msgspec.json.decode(reply.ok.payload.to_bytes(), type=FaultReply).ok
                except msgspec.DecodeError:
                    return False
        return False

    def restart_agent(self, arm: str, sig: signal.Signals) -> tuple[bool, str]:
        """Signal the arm's agent by PID, wait for its exit, start a new one, wait until it
        serves the arm again (token present, link ok)."""
        role = f"agent-{arm}"
        self._restarting.add(role)
        try:
            worker = self.fleet.pids()[role]
            worker.process.send_signal(sig)
            try:
                code: int | None = worker.process.wait(timeout=15.0)
            except subprocess.TimeoutExpired:
                code = None  # worker.stop() kills it by PID
            worker.stop()
            started = time.monotonic()
            self.fleet.start(role)
            deadline = started + READY_TIMEOUT_S
            back = False
            while time.monotonic() < deadline and not back:
                back = arm in self._client().agents_alive() and self._wait_links([arm], 2.0)
            took = time.monotonic() - started
        finally:
            self._restarting.discard(role)
        return back, f"exit code {code}; serving again after {took:.1f} s"

    def viewer_reconnect(self) -> tuple[bool, str]:
        """The page over HTTP, then WebSocket sessions that must each receive scene data."""
        url = f"http://127.0.0.1:{self.fleet.viewer_port}/"
        try:
            with urllib.request.urlopen(url, timeout=10.0) as response:  # noqa: S310 - loopback
                page = len(response.read())
        except OSError as exc:
            return False, f"GET {url}: {exc}"
        version = importlib.metadata.version("viser")
        counts = []
        for _ in range(VIEWER_CLIENTS):
            counts.append(_ws_session(url.replace("http", "ws"), f"viser-v{version}", 2.0))
        ok = page > 0 and all(c > 0 for c in counts)
        return ok, f"page {page} B; messages per session {counts}"

    # ------------------------------------------------------------------ end

    def close(self) -> None:
        """Close the client's subscriptions and session, then every process by PID."""
        for sub in self._subs:
            sub.undeclare()
        if self.client is not None:
            self.client.close()
        self.fleet.close()
        self.record.load_end = os.getloadavg()


def _ws_session(url: str, subprotocol: str, for_s: float) -> int:
    """Messages received by one WebSocket session of ``for_s`` seconds (0 if it failed)."""
    received = 0
    try:
        with ws_connect(url, subprotocols=[subprotocol], open_timeout=10.0) as ws:  # type: ignore[list-item]
            deadline = time.monotonic() + for_s
            while (left := deadline - time.monotonic()) > 0:
                try:
                    ws.recv(timeout=left)
                except TimeoutError:
                    break
                received += 1
    except OSError:
        return 0
    return received


def _stop_text(stamp_ns: int, acks: dict[str, StopAck | None]) -> str:
    """``written 3.1 ms, still 240 ms`` (last arm) or who did not answer."""
    written = [a.dds_written_ns for a in acks.values() if a is not None and a.dds_written_ns]
    still = [a.still_ns for a in acks.values() if a is not None and a.still_ns]
    parts = []
    if written:
        parts.append(f"written {(max(written) - stamp_ns) / 1e6:.1f} ms")
    if still:
        parts.append(f"still {(max(still) - stamp_ns) / 1e6:.0f} ms")
    return ", ".join(parts) or "no ack"


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring."""
    parser = argparse.ArgumentParser(
        prog="python -m bench.soak", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--duration", type=parse_duration, default=parse_duration("30m"))
    parser.add_argument("--out", type=Path, default=REPO / "artifacts" / "soak")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    soak = Soak(args.duration, args.out)
    print(
        f"soak: {args.duration:.0f} s, an event every {soak.period_s:.0f} s, samples every "
        f"{SAMPLE_S:.0f} s; DDS domain {soak.fleet.domain}, router port {soak.fleet.port}, "
        f"viewer http://127.0.0.1:{soak.fleet.viewer_port}/; load {os.getloadavg()[0]:.2f}",
        flush=True,
    )
    # SIGTERM ends the soak like Ctrl-C: the finally below stops every process by PID.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        soak.start()
        soak.run()
    finally:
        soak.close()
    passed = write_report(soak.record, args.out, soak.fleet.incarnation)
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
