"""ROS 2 (issue 27): ``fleet ros2``'s added latency and CPU at 10 arms.

A router, ``fleet ros2`` (its own process), and in this process a feeder that puts ``Joints``
on ``arm/<arm>/joints`` at 10 Hz for every arm (as agents do) and one subscriber on both the
Zenoh joints keys and the ROS ``joint_states`` keys: the added latency of a sample is its
joint_states arrival minus its joints arrival (matched by the sample's stamp, both seen by the
same subscriber). CPU: the ros2 process's user+system time over the measured window.
``python -m bench --only ros2``.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from bench.proc import REPO, cpu_s
from fleet.inventory import load_inventory
from fleet.ros2 import contract as c
from fleet.ros2.grants import topics
from fleet.wire import keys, messages, payloads
from fleet.wire.session import open_client

RATE_HZ = 10.0


def _inventory(path: Path, port: int, arms: int) -> None:
    lines = [f'[fleet]\nname = "bench"\n[zenoh]\nendpoints = ["tcp/127.0.0.1:{port}"]\n']
    lines += ['[defaults]\ninterface = "lo"\nsimulated = true\n', "[ros2]\n"]
    lines += [f'[arms.a{i}]\nsuffix = "_{i}"\n' for i in range(arms)]
    path.write_text("\n".join(lines), encoding="utf-8")


def run(quick: bool, arms: int = 10) -> dict[str, Any]:
    """Added latency p50/p95 (ms) and CPU (% of a core) of ``fleet ros2`` at ``arms`` arms."""
    from testkit.harness import free_port, wait_until

    seconds = 10.0 if quick else 30.0
    port = free_port()
    with tempfile.TemporaryDirectory(prefix="bench-ros2-") as tmp:
        path = Path(tmp) / "inventory.toml"
        _inventory(path, port, arms)
        inventory = load_inventory(path)
        argv = ["--inventory", str(path)]
        py = [sys.executable, "-m", "fleet.cli.main"]
        router = subprocess.Popen([*py, "router", *argv], cwd=REPO, stdout=subprocess.DEVNULL)
        ros2 = None
        try:
            time.sleep(0.5)
            ros2 = subprocess.Popen([*py, "ros2", *argv], cwd=REPO, stdout=subprocess.DEVNULL)
            return _measure(inventory, port, arms, seconds, ros2, wait_until)
        finally:
            for process in (ros2, router):
                if process is not None and process.poll() is None:
                    process.terminate()
                    process.wait(timeout=10)


def _measure(inventory: Any, port: int, arms: int, seconds: float, ros2: Any, wait: Any) -> dict:
    space = keys.KeySpace(inventory.fleet)
    js_keys = {
        c.topic_key(0, fqn, t): fqn.split("/")[2]
        for fqn, t, _l in topics(inventory)
        if fqn.endswith("joint_states")
    }
    zenoh_seen: dict[tuple[str, int], int] = {}
    ros_seen: dict[tuple[str, int], int] = {}
    lock = threading.Lock()

    def on_joints(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        arm = space.parse_arm_key(str(sample.key_expr)).arm
        stamp = payloads.JOINTS.decode(sample.payload.to_bytes()).stamp_ns
        with lock:
            zenoh_seen[(arm, stamp)] = now

    def on_ros(sample: zenoh.Sample) -> None:
        now = time.time_ns()
        stamp = int.from_bytes(sample.attachment.to_bytes()[8:16], "little")
        with lock:
            ros_seen[(js_keys[str(sample.key_expr)], stamp)] = now

    session = open_client([f"tcp/127.0.0.1:{port}"])
    subs = [session.declare_subscriber(space.all_arms(keys.JOINTS), on_joints)]
    subs += [session.declare_subscriber(k, on_ros) for k in js_keys]
    pubs = {a: session.declare_publisher(space.arm(a, keys.JOINTS)) for a in inventory.arms}

    def feed(until: float) -> None:
        seq = 0
        while time.monotonic() < until:
            seq += 1
            for pub in pubs.values():
                pub.put(messages.encode(messages.Joints(time.time_ns(), [1.0 * seq % 90] * 7, seq)))
            time.sleep(1.0 / RATE_HZ)

    try:
        wait(lambda: (feed(time.monotonic() + 0.3), len(ros_seen) > 0)[1], 30.0)  # ros2 is up
        with lock:
            zenoh_seen.clear()
            ros_seen.clear()
        cpu0, t0 = cpu_s(ros2.pid), time.monotonic()
        feed(t0 + seconds)
        cpu = (cpu_s(ros2.pid) - cpu0) / (time.monotonic() - t0) * 100.0
        time.sleep(0.3)
    finally:
        for sub in subs:
            sub.undeclare()
        session.close()
    added = sorted((ros_seen[k] - t) / 1e6 for k, t in zenoh_seen.items() if k in ros_seen)
    return {
        "arms": arms,
        "rate_hz": RATE_HZ,
        "samples": len(added),
        "lost": len(zenoh_seen) - len(added),
        "added_ms_p50": statistics.median(added) if added else None,
        "added_ms_p95": added[int(0.95 * (len(added) - 1))] if added else None,
        "cpu_pct": cpu,
        "goal": "p50 <= 2 ms, CPU <= 3 % of a core at 10 arms",
    }


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
