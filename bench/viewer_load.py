"""CPU of the viewer process at several fleet sizes, with synthetic traffic at 10 Hz.

``python -m bench.viewer_load --arms 3 10 50 200 [--browser] [--g1 ID]`` starts, per fleet size, a
router, the synthetic publisher (bench/synthetic.py) and ``fleet viewer`` as separate processes,
optionally a headless Chromium showing the page, then reads the viewer's CPU time from
/proc/<pid>/stat (utime + stime) over a window and prints one JSON line per size. With ``--g1 ID``
the inventory has a ``[g1.<id>]`` too (drawn beside the arms) and the synthetic publisher relays
its lowstate and state at its ``relay_hz``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench import synthetic
from fleet.inventory import parse_inventory

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def inventory_text(arms: int, port: int, g1s: tuple[str, ...] = ()) -> str:
    """An inventory of ``arms`` arms on a square grid, 0.7 m apart, and the G1s ``g1s`` (their
    defaults: placed beside the arms, relayed at the config's ``relay_hz``)."""
    side = math.ceil(math.sqrt(arms))
    lines = [
        '[fleet]\nname = "bench"\n',
        f'[zenoh]\nendpoints = ["tcp/127.0.0.1:{port}"]\n',
        "[defaults]\nsimulated = true\n",
    ]
    for i in range(arms):
        x, y = 0.7 * (i % side), 0.7 * (i // side)
        lines.append(f'[arms.b{i + 1}]\nsuffix = "_{i + 1}"\nbase_xyz = [{x:.2f}, {y:.2f}, 0.0]\n')
    lines += [f"[g1.{g1}]\n" for g1 in g1s]
    return "\n".join(lines)


def cpu_s(pid: int) -> float:
    """utime + stime of ``pid`` in seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def free_port() -> int:
    """A free TCP port on 127.0.0.1."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _wait_for_line(path: Path, needle: str, timeout_s: float) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in path.read_text(errors="replace").splitlines():
            if needle in line:
                return line
        time.sleep(0.1)
    raise TimeoutError(f"{needle!r} not in {path} within {timeout_s} s")


def measure(
    arms: int, window_s: float, browser: bool, workdir: Path, g1s: tuple[str, ...] = ()
) -> dict[str, Any]:
    """One fleet size (and the G1s ``g1s``): start everything, measure the viewer's CPU over
    ``window_s``."""
    port = free_port()
    run = f"{arms}{''.join(f'-{g1}' for g1 in g1s)}"
    inv = workdir / f"inventory-{run}.toml"
    inv.write_text(inventory_text(arms, port, g1s), encoding="utf-8")
    common = ["--inventory", str(inv), "--log-level", "WARNING"]
    logs = {name: workdir / f"{name}-{run}.log" for name in ("router", "synthetic", "viewer")}
    g1_options = [option for g1 in g1s for option in ("--g1", g1)]
    argvs = {
        "router": ["-m", "fleet.cli.main", "router", *common],
        "synthetic": ["-m", "bench.synthetic", "--rate-hz", "10", *g1_options, *common],
        "viewer": ["-m", "fleet.cli.main", "viewer", "--port", str(free_port()), *common],
    }
    procs: dict[str, subprocess.Popen[bytes]] = {}
    result: dict[str, Any] = {"arms": arms, "rate_hz": 10, "browser": browser}
    if g1s:
        inventory = parse_inventory(inv.read_text(encoding="utf-8"), str(inv))
        configs = synthetic.g1_configs(inventory, list(g1s))
        result["g1_relay_hz"] = {config.id: config.relay_hz for config in configs}
    try:
        for name, argv in argvs.items():
            with open(logs[name], "wb") as log:
                procs[name] = subprocess.Popen(
                    [sys.executable, *argv], stdout=log, stderr=subprocess.STDOUT
                )
            time.sleep(0.5 if name == "router" else 0.0)
        line = _wait_for_line(logs["viewer"], "d1-fleet viewer: http", 60.0)
        url = line.split("d1-fleet viewer: ", 1)[1].split()[0]
        if browser:
            result.update(_measure_with_browser(url, procs["viewer"].pid, window_s))
        else:
            time.sleep(5.0)  # warm-up: first samples, tokens, allocations
            result.update(_cpu_window(procs["viewer"].pid, window_s))
    finally:
        for proc in reversed(list(procs.values())):
            proc.terminate()
        for proc in procs.values():
            try:
                proc.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                proc.kill()
    return result


def _cpu_window(
    pid: int, window_s: float, sleep: Callable[[float], None] = time.sleep
) -> dict[str, Any]:
    c0, t0 = cpu_s(pid), time.monotonic()
    sleep(window_s)
    c1, t1 = cpu_s(pid), time.monotonic()
    return {"viewer_cpu_percent_of_a_core": round(100.0 * (c1 - c0) / (t1 - t0), 1)}


def _measure_with_browser(url: str, pid: int, window_s: float) -> dict[str, Any]:
    from playwright.sync_api import sync_playwright  # only the --browser runs need it

    frames = [0, 0]

    def on_ws(ws: Any) -> None:
        def on_frame(payload: str | bytes) -> None:
            frames[0] += 1
            frames[1] += len(payload)

        ws.on("framereceived", on_frame)

    with sync_playwright() as pw, tempfile.TemporaryDirectory() as profile:
        context = pw.chromium.launch_persistent_context(
            profile,
            executable_path="/usr/bin/chromium",
            headless=True,
            args=["--headless", "--no-sandbox", "--enable-unsafe-swiftshader",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--no-first-run"],
        )  # fmt: skip
        page = context.new_page()
        page.on("websocket", on_ws)
        page.goto(url)
        page.locator("canvas").first.wait_for(timeout=60_000)
        page.wait_for_timeout(5000)
        f0, b0, t0 = frames[0], frames[1], time.monotonic()
        # Playwright delivers websocket events only while it has control: wait through it.
        cpu = _cpu_window(pid, window_s, lambda s: page.wait_for_timeout(s * 1000.0))
        dt = time.monotonic() - t0
        out = {
            **cpu,
            "ws_frames_per_s": round((frames[0] - f0) / dt, 1),
            "ws_kbytes_per_s": round((frames[1] - b0) / dt / 1000.0, 1),
        }
        context.close()
    return out


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: one JSON line per fleet size."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--arms", type=int, nargs="+", default=[3, 10, 50, 200])
    parser.add_argument("--window-s", type=float, default=10.0)
    parser.add_argument("--browser", action="store_true", help="keep a headless Chromium open")
    parser.add_argument("--g1", action="append", default=[], metavar="ID", help="and a G1")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for arms in args.arms:
            result = measure(arms, args.window_s, args.browser, Path(tmp), tuple(args.g1))
            print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
