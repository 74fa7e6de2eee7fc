"""Probe: does one UDP session whose messages block at a Zenoh router hold up every other UDP
session's datagrams there? (docs/design/stop-path.md, 30 % loss.)

On loopback: a router with a ``tcp/`` and a ``udp/`` endpoint; a subscriber on TCP that is then
frozen (SIGSTOP), so the router's queue towards it fills; a flooder putting blocking
(``CongestionControl.BLOCK``) messages to it, over TCP in one trial and over UDP in the next;
and, beside them, a UDP session putting a beat every 10 ms to a third session, whose largest
gap between two beats is printed. Measured with Zenoh 1.10.2 (2026-11-27): 14-21 ms with the
flood over TCP, 510-513 ms (the router's ``wait_before_close``) with the same flood over UDP.

    .venv/bin/python scripts/zenoh_udp_hol.py
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fleet.wire.session import Datagram, open_datagram, zenoh_config  # noqa: E402
from testkit.harness import free_port  # noqa: E402

FROZEN = """
import sys, time, zenoh
from fleet.wire.session import zenoh_config
session = zenoh.open(zenoh_config("client", connect=[sys.argv[1]]))
subscriber = session.declare_subscriber("probe/block/**", lambda sample: None)
print("ready", flush=True)
time.sleep(60)
"""
FLOOD_S = 2.0
BEAT_S = 0.01


def trial(flood_over: str) -> float:
    """The largest gap (s) between beats of one UDP session while another floods over
    ``flood_over`` (tcp or udp) towards a frozen subscriber."""
    tcp = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(zenoh_config("router", listen=[tcp], datagram=Datagram()))
    root = str(Path(__file__).resolve().parents[1])
    frozen = subprocess.Popen(
        [sys.executable, "-c", FROZEN, tcp],
        stdout=subprocess.PIPE,
        env={**os.environ, "PYTHONPATH": root},
    )
    sessions: list[zenoh.Session] = [router]
    try:
        assert frozen.stdout is not None and frozen.stdout.readline().startswith(b"ready")
        beater = open_datagram([tcp], Datagram(), 5.0)
        listener = zenoh.open(zenoh_config("client", connect=[tcp]))
        if flood_over == "udp":
            flooder = open_datagram([tcp], Datagram(), 5.0)
        else:
            flooder = zenoh.open(zenoh_config("client", connect=[tcp]))
        assert beater is not None and flooder is not None
        sessions += [beater, listener, flooder]
        arrivals: list[float] = []
        listener.declare_subscriber("probe/beat", lambda _s: arrivals.append(time.monotonic()))
        time.sleep(0.5)  # the declarations reached the router
        done = threading.Event()

        def beats() -> None:
            for _ in range(int((FLOOD_S + 3.0) / BEAT_S)):  # bounded
                if done.wait(BEAT_S):
                    return
                beater.put("probe/beat", b"x", express=True)

        thread = threading.Thread(target=beats, daemon=True)
        thread.start()
        time.sleep(0.5)
        os.kill(frozen.pid, signal.SIGSTOP)
        end = time.monotonic() + FLOOD_S
        while time.monotonic() < end:
            flooder.put(
                "probe/block/x",
                b"y" * 1000,
                congestion_control=zenoh.CongestionControl.BLOCK,
                express=True,
            )
        time.sleep(1.0)  # the beats after the flood: a window, not a wait for a state
        done.set()
        thread.join(timeout=2.0)
        gaps = [b - a for a, b in zip(arrivals, arrivals[1:])]
        return max(gaps, default=float("inf"))
    finally:
        os.kill(frozen.pid, signal.SIGCONT)
        frozen.kill()
        frozen.wait()
        for session in reversed(sessions):
            session.close()  # type: ignore[no-untyped-call]


def main() -> None:
    for flood_over in ("tcp", "udp", "tcp", "udp"):
        gap = trial(flood_over)
        print(f"blocking flood over {flood_over}: the beats' largest gap {gap * 1e3:.0f} ms")


if __name__ == "__main__":
    main()
