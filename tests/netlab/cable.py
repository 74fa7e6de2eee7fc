"""The lab's cables: a userspace netem, one process in the switch namespace for every link.

Why userspace: the kernel this suite runs on has no ``sch_netem`` (nor ``fq``, ``gact`` or
``nft queue``), so ``tc netem`` cannot delay, drop, duplicate or reorder anything here. Each
link of the lab is therefore a pair of TAP devices joined by this process: the host end (moved
into the host's namespace by the lab) and the switch end (a port of the switch namespace's
Linux bridge). Every Ethernet frame crossing the link passes through here, in both directions,
and gets the link's impairment, netem style:

- ``loss``: probability a frame is dropped (each direction, independently);
- ``delay_ms`` (+ ``jitter_ms``, uniform +-): time a frame spends on the cable;
- ``duplicate``: probability a frame is delivered twice;
- ``reorder``: probability a frame skips the delay (so it overtakes the delayed ones);
- ``down``: every frame is dropped (a partition; the hosts keep their carrier).

TAP devices have no offloads, so frames carry full checksums and are at most one MTU: nothing
needs ``ethtool`` here, unlike a veth read with ``AF_PACKET``. Closing the process removes every
TAP device it made (they are not persistent).

Control: one JSON object per line on stdin, one JSON reply per line on stdout:
``{"op": "add", "link": L, "host_if": H, "switch_if": S}`` makes the two TAP devices;
``{"op": "set", "link": L, "loss": 0.1, "delay_ms": 20, ...}`` replaces the link's impairment;
``{"op": "stats"}`` returns the frame counters of every link. EOF on stdin ends the process.
"""

from __future__ import annotations

import fcntl
import heapq
import json
import os
import random
import selectors
import struct
import sys
import time
from dataclasses import asdict, dataclass, field

TUNSETIFF = 0x400454CA
IFF_TAP = 0x0002
IFF_NO_PI = 0x1000
MAX_FRAME = 65536
MAX_QUEUED = 20000
"""Frames on all cables at once; beyond that new frames are dropped (counted), like a full
netem queue (its default limit is 1000 per qdisc)."""


@dataclass(frozen=True)
class Impairment:
    """What one link does to every frame (the same both ways, like netem on both veth ends)."""

    loss: float = 0.0
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    down: bool = False


@dataclass
class Counters:
    """Frames seen on one link (both directions)."""

    frames: int = 0
    dropped: int = 0
    duplicated: int = 0
    overflow: int = 0
    write_errors: int = 0


@dataclass
class Link:
    """The two TAP file descriptors of one link and its impairment."""

    name: str
    host_fd: int
    switch_fd: int
    impairment: Impairment = field(default_factory=Impairment)
    counters: Counters = field(default_factory=Counters)


def open_tap(name: str) -> int:
    """A non-blocking TAP device ``name`` in this process's namespace (gone when closed)."""
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    try:
        fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TAP | IFF_NO_PI))
    except OSError:
        os.close(fd)
        raise
    return fd


class Cables:
    """Every link of one lab: reads frames, impairs them, writes them out when due."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        self.links: dict[str, Link] = {}
        self.selector = selectors.DefaultSelector()
        self.queue: list[tuple[float, int, int, bytes]] = []  # (due, n, out fd, frame)
        self.n = 0

    def add(self, name: str, host_if: str, switch_if: str) -> None:
        """Make the link's two TAP devices."""
        host_fd = open_tap(host_if)
        switch_fd = open_tap(switch_if)
        link = Link(name, host_fd, switch_fd)
        self.links[name] = link
        self.selector.register(host_fd, selectors.EVENT_READ, (link, switch_fd))
        self.selector.register(switch_fd, selectors.EVENT_READ, (link, host_fd))

    def receive(self, fd: int, link: Link, out_fd: int, now: float) -> None:
        """Take every frame waiting on ``fd`` and schedule it on ``out_fd``."""
        imp = link.impairment
        while True:
            try:
                frame = os.read(fd, MAX_FRAME)
            except BlockingIOError:
                return
            except OSError:  # the device went away (namespace deleted)
                return
            link.counters.frames += 1
            if imp.down or (imp.loss > 0 and self.rng.random() < imp.loss):
                link.counters.dropped += 1
                continue
            copies = 2 if imp.duplicate > 0 and self.rng.random() < imp.duplicate else 1
            link.counters.duplicated += copies - 1
            for _ in range(copies):
                self.schedule(link, out_fd, frame, now)

    def schedule(self, link: Link, out_fd: int, frame: bytes, now: float) -> None:
        """Queue one frame for its due time."""
        imp = link.impairment
        if len(self.queue) >= MAX_QUEUED:
            link.counters.overflow += 1
            return
        delay_s = imp.delay_ms / 1000.0
        if imp.jitter_ms > 0:
            delay_s += self.rng.uniform(-imp.jitter_ms, imp.jitter_ms) / 1000.0
        if imp.reorder > 0 and self.rng.random() < imp.reorder:
            delay_s = 0.0
        self.n += 1
        heapq.heappush(self.queue, (now + max(0.0, delay_s), self.n, out_fd, frame))

    def send_due(self, now: float) -> None:
        """Write out every frame whose time has come."""
        while self.queue and self.queue[0][0] <= now:
            _due, _n, fd, frame = heapq.heappop(self.queue)
            try:
                os.write(fd, frame)
            except OSError:  # the far end is down or gone: the frame is lost, like on a wire
                for link in self.links.values():
                    if fd in (link.host_fd, link.switch_fd):
                        link.counters.write_errors += 1

    def control(self, line: str) -> dict[str, object]:
        """Apply one control request."""
        request = json.loads(line)
        op = request.pop("op")
        if op == "add":
            self.add(request["link"], request["host_if"], request["switch_if"])
            return {"ok": True}
        if op == "set":
            link = self.links[request.pop("link")]
            link.impairment = Impairment(**request)
            return {"ok": True, "impairment": asdict(link.impairment)}
        if op == "stats":
            return {"ok": True, "links": {n: asdict(k.counters) for n, k in self.links.items()}}
        return {"ok": False, "error": f"unknown op {op!r}"}

    def run(self) -> None:
        """Serve until stdin closes."""
        stdin = sys.stdin.fileno()
        os.set_blocking(stdin, False)
        self.selector.register(stdin, selectors.EVENT_READ, None)
        pending = b""
        while True:
            timeout = None
            if self.queue:
                timeout = max(0.0, self.queue[0][0] - time.monotonic())
            events = self.selector.select(timeout)
            now = time.monotonic()
            for key, _mask in events:
                if key.data is None:
                    chunk = os.read(stdin, 65536)
                    if not chunk:
                        return
                    pending += chunk
                    while b"\n" in pending:
                        line, pending = pending.split(b"\n", 1)
                        try:
                            reply = self.control(line.decode())
                        except (OSError, KeyError, TypeError, ValueError) as exc:
                            reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
                        sys.stdout.write(json.dumps(reply) + "\n")
                        sys.stdout.flush()
                else:
                    link, out_fd = key.data
                    self.receive(key.fd, link, out_fd, now)
            self.send_due(time.monotonic())


def main() -> int:
    """``python -m tests.netlab.cable SEED`` (run inside the switch namespace)."""
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 0
    Cables(seed).run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
