"""ROS 2: ``fleet ros2``'s added latency and CPU at 10 arms.

A router, ``fleet ros2`` (its own process), and in this process a feeder that puts ``Joints``
on ``arm/<arm>/joints`` at 10 Hz for every arm (as agents do) and one subscriber on both the
Zenoh joints keys and the ROS ``joint_states`` keys: the added latency of a sample is its
joint_states arrival minus its joints arrival (matched by the sample's stamp, both seen by the
same subscriber). CPU: the ros2 process's user+system time over the measured window. The load
average is reported with the numbers (a loaded 2-core host doubles them).

A no-op relay runs next to it (``floor``: a Python process that takes each joints sample on a
Zenoh callback, decodes it and puts it on ``bench_relay/<arm>``): the least any process of
ours adds on this host at this load, the floor under ``fleet ros2``'s number.

``python -m bench.ros2 --against main`` also runs the ``fleet ros2`` of another revision (its
``git archive``, in a temporary directory, with this venv) on ROS domain 1, at the same time,
on the same samples: the two rows' ratio holds whatever the load was.
``python -m bench --only ros2``.
"""

from __future__ import annotations

import os
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
RELAY = "bench_relay"


def relay(endpoint: str) -> None:
    """The floor: joints -> ``bench_relay/<arm>`` on the Zenoh callback, with the attachment's
    source timestamp as rmw_zenoh's, until stdin closes or SIGTERM."""
    import signal
    import struct

    space = keys.KeySpace("bench")
    session = open_client([endpoint])

    def on_joints(sample: zenoh.Sample) -> None:
        arm = str(sample.key_expr).split("/")[3]
        stamp = payloads.JOINTS.decode(sample.payload.to_bytes()).stamp_ns
        attachment = struct.pack("<qqB16s", 1, stamp, 16, bytes(16))
        session.put(f"{RELAY}/{arm}", b"x", attachment=attachment)

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    sub = session.declare_subscriber(space.all_arms(keys.JOINTS), on_joints)
    stop.wait()
    sub.undeclare()
    session.close()


def _inventory(path: Path, port: int, arms: int, domain: int = 0) -> None:
    lines = [f'[fleet]\nname = "bench"\n[zenoh]\nendpoints = ["tcp/127.0.0.1:{port}"]\n']
    lines += ['[defaults]\ninterface = "lo"\nsimulated = true\n', f"[ros2]\ndomain_id = {domain}\n"]
    lines += [f'[arms.a{i}]\nsuffix = "_{i}"\n' for i in range(arms)]
    path.write_text("\n".join(lines), encoding="utf-8")


def run(quick: bool, arms: int = 10, against: str | None = None) -> dict[str, Any]:
    """Added latency p50/p95 (ms) and CPU (% of a core) of ``fleet ros2`` at ``arms`` arms; with
    ``against`` (a git revision) the same of that revision's, measured at the same time."""
    from testkit.harness import free_port, wait_until

    seconds = 10.0 if quick else 30.0
    port = free_port()
    with tempfile.TemporaryDirectory(prefix="bench-ros2-") as tmp:
        path = Path(tmp) / "inventory.toml"
        _inventory(path, port, arms)
        inventory = load_inventory(path)
        argv = ["--inventory", str(path)]
        py = [sys.executable, "-m", "fleet.cli.main"]
        runs = {"current": (REPO, path)}
        if against is not None:
            tree = Path(tmp) / "baseline"
            tree.mkdir()
            archive = subprocess.run(
                ["git", "-C", str(REPO), "archive", against], check=True, capture_output=True
            ).stdout
            subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
            base_path = Path(tmp) / "baseline.toml"
            _inventory(base_path, port, arms, domain=1)
            runs[against] = (tree, base_path)
        router = subprocess.Popen([*py, "router", *argv], cwd=REPO, stdout=subprocess.DEVNULL)
        processes: dict[str, subprocess.Popen[bytes]] = {}
        try:
            wait_until(lambda: _listening(port), 20.0)
            for name, (cwd, inv) in runs.items():
                processes[name] = subprocess.Popen(
                    [*py, "ros2", "--inventory", str(inv)], cwd=cwd, stdout=subprocess.DEVNULL
                )
            relay = [sys.executable, "-m", "bench.ros2", "--relay", f"tcp/127.0.0.1:{port}"]
            processes["floor"] = subprocess.Popen(relay, cwd=REPO, stdout=subprocess.DEVNULL)
            out = _measure(inventory, port, arms, seconds, processes, wait_until)
            out["load_avg_1m_5m"] = [round(v, 2) for v in os.getloadavg()[:2]]
            if against is not None:
                now, then = out, out[against]
                out["ratio_to_" + against] = {
                    k: round(now[k] / then[k], 3) if then[k] else None
                    for k in ("added_ms_p50", "added_ms_p95", "cpu_pct")
                }
            return out
        finally:
            for process in (*processes.values(), router):
                if process.poll() is None:
                    process.terminate()
                    process.wait(timeout=10)


def _listening(port: int) -> bool:
    import socket

    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _stats(added: list[float], sent: int, cpu: float) -> dict[str, Any]:
    added.sort()
    return {
        "samples": len(added),
        "lost": sent - len(added),
        "added_ms_p50": statistics.median(added) if added else None,
        "added_ms_p95": added[int(0.95 * (len(added) - 1))] if added else None,
        "cpu_pct": cpu,
    }


def _measure(
    inventory: Any, port: int, arms: int, seconds: float, ros2: dict[str, Any], wait: Any
) -> dict[str, Any]:
    space = keys.KeySpace(inventory.fleet)
    js_keys = {f"{RELAY}/{arm}": ("floor", arm) for arm in inventory.arms}
    for domain, name in enumerate(n for n in ros2 if n != "floor"):
        for fqn, t, _l in topics(inventory):
            if fqn.endswith("joint_states"):
                js_keys[c.topic_key(domain, fqn, t)] = (name, fqn.split("/")[2])
    zenoh_seen: dict[tuple[str, int], int] = {}
    ros_seen: dict[tuple[str, str, int], int] = {}
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
            ros_seen[(*js_keys[str(sample.key_expr)], stamp)] = now

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

    def up() -> bool:
        feed(time.monotonic() + 0.3)
        with lock:
            return {name for name, _arm, _stamp in ros_seen} == set(ros2)

    try:
        wait(up, 30.0)
        with lock:
            zenoh_seen.clear()
            ros_seen.clear()
        cpu0 = {name: cpu_s(p.pid) for name, p in ros2.items()}
        t0 = time.monotonic()
        feed(t0 + seconds)
        elapsed = time.monotonic() - t0
        cpu = {name: (cpu_s(p.pid) - cpu0[name]) / elapsed * 100.0 for name, p in ros2.items()}
        time.sleep(0.3)
    finally:
        for sub in subs:
            sub.undeclare()
        session.close()
    out: dict[str, Any] = {"arms": arms, "rate_hz": RATE_HZ}
    for name in ros2:
        arrived = {(arm, stamp): t for (n, arm, stamp), t in ros_seen.items() if n == name}
        added = [(arrived[k] - t) / 1e6 for k, t in zenoh_seen.items() if k in arrived]
        stats = _stats(added, len(zenoh_seen), cpu[name])
        if name == "current":
            out.update(stats)
        else:
            out[name] = stats
    out["goal"] = "p50 <= 2 ms, CPU <= 3 % of a core at 10 arms"
    return out


if __name__ == "__main__" and "--relay" in sys.argv:
    relay(sys.argv[sys.argv.index("--relay") + 1])
elif __name__ == "__main__":
    rev = sys.argv[sys.argv.index("--against") + 1] if "--against" in sys.argv else None
    print(run(quick="--quick" in sys.argv, against=rev))
