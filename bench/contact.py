"""Labelled contact-detection benchmark on the pure simulator model (no transport, seeded).

``bench_contact()`` runs >= 200 scripted episodes (free motion at many speeds and step sizes,
stalls on every arm joint at several speeds, gripping an object vs closing on air, a held joint
pushed by a moving obstacle, joints dragged by hand while unloaded; noise and feedback jitter on
part of them), each labelled with the true contact onset (the first physics step in which the
joint is blocked). It prints, per method and for the default combination (the detector's own
CONFIRMED state): recall, false alarms per hour of free motion, detection delay p50/p95.
Run: ``python -m bench.contact``.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field

from fleet.contact.config import METHODS, ContactConfig
from fleet.contact.detector import ContactDetector, ContactState
from fleet.contact.feed import feed_command
from fleet.d1 import protocol as p
from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.sim.model import SimArmModel
from fleet.sim.obstacles import Obstacle

DEFAULT = "default"


@dataclass
class Episode:
    """One scripted run. ``contact_joint`` None: no contact may be reported."""

    name: str
    kind: str
    seed: int
    duration_s: float
    start: list[float]
    commands: list[tuple[float, p.Command]]
    contact_joint: int | None = None
    obstacle: Obstacle | None = None
    noise_deg: float = 0.0
    jitter_s: float = 0.0
    unloaded: tuple[int, ...] = ()
    drags: dict[int, tuple[float, float]] = field(default_factory=dict)


@dataclass
class Outcome:
    """Labels and detections of one episode (times in seconds from its start)."""

    episode: Episode
    onset_s: float | None
    confirmations: dict[str, list[tuple[int, float]]]  # method -> (joint, time)


def _pose(rng: random.Random, spread: float = 0.5) -> list[float]:
    return [rng.uniform(lo * spread, hi * spread) for lo, hi in JOINT_RANGE_DEG]


def _clamp(joint: int, angle: float) -> float:
    lo, hi = JOINT_RANGE_DEG[joint]
    return min(max(angle, lo), hi)


def _steps(
    rng: random.Random, start: list[float], t0: float, n: int
) -> list[tuple[float, p.Command]]:
    """Moves of many sizes in both smoothing modes (1/2), and single-joint moves (1/1)."""
    out: list[tuple[float, p.Command]] = []
    pose, t = list(start), t0
    for _ in range(n):
        size = rng.choice([2.0, 5.0, 10.0, 20.0, 40.0, 60.0, 90.0, 120.0])
        if rng.random() < 0.3:
            j = rng.randrange(7)
            pose[j] = _clamp(j, pose[j] + rng.choice([-1, 1]) * size)
            out.append((t, p.SetJointAngle(j, round(pose[j], 2))))
        else:
            for j in rng.sample(range(7), rng.randint(1, 7)):
                pose[j] = _clamp(j, pose[j] + rng.choice([-1, 1]) * size * rng.uniform(0.5, 1))
            out.append((t, p.SetAllAngles(tuple(round(a, 2) for a in pose), rng.choice([0, 1]))))
        t += rng.uniform(0.3, 2.5)
    return out


def _stream(
    start: list[float], joints: dict[int, float], t0: float, duration: float
) -> list[tuple[float, p.Command]]:
    """10 Hz mode-0 streaming: each joint in ``joints`` ramps at that speed (deg/s)."""
    out: list[tuple[float, p.Command]] = []
    for k in range(int(duration * 10)):
        t = t0 + k * 0.1
        pose = [_clamp(j, start[j] + joints.get(j, 0.0) * (t - t0)) for j in range(len(start))]
        out.append((t, p.SetAllAngles(tuple(round(a, 2) for a in pose), 0)))
    return out


def episodes(seed: int = 7) -> list[Episode]:
    """The seeded suite (>= 200 episodes)."""
    rng = random.Random(seed)
    eps: list[Episode] = []

    def noise() -> tuple[float, float]:
        return rng.choice([(0.0, 0.0), (0.0, 0.0), (0.05, 0.02), (0.1, 0.03)])

    for i in range(60):  # free: steps of every size, both modes
        start = _pose(rng)
        n, jit = noise()
        cmds = _steps(rng, start, 0.5, rng.randint(3, 6))
        eps.append(
            Episode(
                f"free-steps-{i}", "free", i, cmds[-1][0] + 3.0, start, cmds, None, None, n, jit
            )
        )
    for i in range(30):  # free: streaming at many speeds
        start = _pose(rng, 0.3)
        speeds = {j: rng.choice([-1, 1]) * rng.uniform(5, 90) for j in rng.sample(range(6), 2)}
        n, jit = noise()
        eps.append(
            Episode(
                f"free-stream-{i}",
                "free",
                100 + i,
                6.0,
                start,
                _stream(start, speeds, 0.5, 4.0),
                None,
                None,
                n,
                jit,
            )
        )
    for i in range(10):  # closing on air and opening
        start = _pose(rng)
        start[6] = 60.0
        cmds: list[tuple[float, p.Command]] = [
            (0.5, p.SetJointAngle(6, 0.0)),
            (3.0, p.SetJointAngle(6, 65.0)),
        ]
        eps.append(Episode(f"air-{i}", "air", 200 + i, 5.5, start, cmds, None, None, *noise()))
    for i in range(8):  # dragged by hand while unloaded
        start = _pose(rng)
        j = rng.randrange(6)
        drag = (_clamp(j, start[j] + rng.choice([-40, 40])), rng.uniform(10, 60))
        cmds = [(0.3, p.SetJointTorque(j, False))]
        eps.append(
            Episode(
                f"drag-{i}",
                "free",
                300 + i,
                5.0,
                start,
                cmds,
                None,
                None,
                *noise(),
                drags={j: drag},
            )
        )
    k = 0
    for joint in range(6):  # stalls on every arm joint at several speeds
        for how in ("mode0", "mode1", "stream20", "stream60"):
            for _rep in range(3):
                k += 1
                eps.append(_stall(rng, joint, how, k, noise()))
    for i in range(15):  # gripping an object
        start = _pose(rng)
        start[6] = 60.0
        width = rng.uniform(8, 45)
        obstacle = Obstacle(width, rng.uniform(0.0, 0.1), side=-1)
        cmds = [(0.5, p.SetJointAngle(6, 0.0))]
        eps.append(Episode(f"grip-{i}", "grip", 500 + i, 4.0, start, cmds, 6, obstacle, *noise()))
    for i in range(10):  # a held joint pushed by a moving obstacle (unexpected contact)
        start = _pose(rng)
        j = rng.randrange(6)
        sign = rng.choice([-1, 1])
        obstacle = Obstacle(
            start[j] + sign * 5.0,
            0.1,
            to_deg=start[j] - sign * 25.0,
            speed_deg_s=rng.uniform(5, 30),
        )
        eps.append(Episode(f"push-{i}", "push", 600 + i, 4.0, start, [], j, obstacle, *noise()))
    return eps


def _stall(rng: random.Random, joint: int, how: str, k: int, nz: tuple[float, float]) -> Episode:
    lo, hi = JOINT_RANGE_DEG[joint]
    sign = rng.choice([-1, 1])
    start = _pose(rng, 0.3)
    start[joint] = -sign * rng.uniform(0, 0.3) * hi
    wall = start[joint] + sign * rng.uniform(10, 40)
    goal = _clamp(joint, wall + sign * rng.uniform(12, 40))
    obstacle = Obstacle(
        wall,
        rng.choice([0.0, 0.05, 0.15]),
        hunting_deg=rng.choice([0.0, 0.0, 1.0]),
        error_after_s=rng.choice([None, 0.4]),
    )
    if how.startswith("stream"):
        speed = sign * float(how[6:])
        cmds = _stream(start, {joint: speed}, 0.5, abs(goal - start[joint]) / abs(speed) + 0.5)
    else:
        target = list(start)
        target[joint] = goal
        cmds = [(0.5, p.SetAllAngles(tuple(round(a, 2) for a in target), int(how[4])))]
    return Episode(
        f"stall-j{joint}-{how}-{k}",
        "stall",
        400 + k,
        cmds[-1][0] + 3.0,
        start,
        cmds,
        joint,
        obstacle,
        *nz,
    )


def run(ep: Episode, config: ContactConfig) -> Outcome:
    """Play ``ep`` on the model and a detector; deliver feedback with latency and jitter."""
    rng = random.Random(ep.seed)
    model = SimArmModel(angles_deg=list(ep.start), target_deg=list(ep.start), rng=rng)
    model.faults.noise_deg, model.faults.drags = ep.noise_deg, dict(ep.drags)
    if ep.obstacle is not None and ep.contact_joint is not None:
        model.faults.obstacles[ep.contact_joint] = ep.obstacle
    det = ContactDetector(config)
    det.on_targets(dict(enumerate(ep.start)), 1, 0.0)
    commands = list(ep.commands)
    found: dict[str, list[tuple[int, float]]] = {}
    onset: float | None = None
    t, reports = rng.uniform(0.0, 0.1), 0
    while t < ep.duration_s:
        while commands and commands[0][0] <= t:
            sent, command = commands.pop(0)
            model.advance(sent + 0.002)
            feed_command(det, command, sent)
            model.apply(p.encode_command(command, 1))
        model.advance(t)
        ob = ep.obstacle
        if onset is None and ob is not None and ob.pushing_s > 0:
            onset = t - ob.pushing_s
        arrive = t + rng.uniform(0.0005, 0.003) + rng.uniform(0.0, ep.jitter_s)
        if reports % 5 == 0:
            status = model.status_reports()[0]
            assert isinstance(status, p.D1Status)
            det.on_status(status.error, status.enabled, status.powered, arrive)
        joints = model.joint_report()
        assert joints is not None
        for change in det.on_angles(joints.angles_deg, arrive).changes:
            if change.state is ContactState.CONFIRMED:
                found.setdefault(DEFAULT, []).append((change.joint, arrive))
        reports += 1
        t += rng.uniform(0.100, 0.111) + rng.uniform(0.0, ep.jitter_s)
    for j in range(7):
        for method, times in det.confirmations(j).items():
            found.setdefault(method, []).extend((j, s) for s in times)
    return Outcome(ep, onset, found)


def _pct(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[max(1, math.ceil(q / 100 * len(ordered))) - 1]


def score(outcomes: list[Outcome], method: str) -> dict[str, float]:
    """Recall per contact kind, false alarms (count, per hour of free motion), delays (ms)."""
    hits: dict[str, list[bool]] = {"stall": [], "grip": [], "push": []}
    delays: list[float] = []
    false_alarms, free_s = 0, 0.0
    for out in outcomes:
        ep, onset = out.episode, out.onset_s
        found = out.confirmations.get(method, [])
        free_s += ep.duration_s if onset is None else onset
        if ep.contact_joint is None or onset is None:
            false_alarms += len(found)
            continue
        good = [s for j, s in found if j == ep.contact_joint and s >= onset]
        false_alarms += sum(1 for j, s in found if j != ep.contact_joint or s < onset)
        hits[ep.kind].append(bool(good))
        if good:
            delays.append((min(good) - onset) * 1000.0)
    row = {f"{k}_recall": 100.0 * sum(v) / len(v) if v else math.nan for k, v in hits.items()}
    row |= {
        "false_alarms": false_alarms,
        "fa_per_h": false_alarms / (free_s / 3600.0),
        "p50_ms": _pct(delays, 50),
        "p95_ms": _pct(delays, 95),
        "max_ms": max(delays) if delays else math.nan,
        "free_h": free_s / 3600.0,
    }
    return row


def bench_contact(
    seed: int = 7, config: ContactConfig | None = None
) -> dict[str, dict[str, float]]:
    """Run the suite and print the table; returns the rows (method -> figures)."""
    config = config or ContactConfig()
    started = time.perf_counter()
    suite = episodes(seed)
    outcomes = [run(ep, config) for ep in suite]
    rows = {m: score(outcomes, m) for m in (*METHODS, DEFAULT)}
    kinds = {
        k: sum(1 for e in suite if e.kind == k) for k in ("free", "air", "stall", "grip", "push")
    }
    print(
        f"contact detection: {len(suite)} episodes {kinds}, "
        f"{rows[DEFAULT]['free_h'] * 60:.1f} min of free motion, "
        f"{time.perf_counter() - started:.1f} s; default = {'+'.join(config.methods)}"
    )
    print(
        "| method | stall recall | grip recall | push recall | false alarms (per h) "
        "| delay p50 / p95 / max ms |"
    )
    print("|---|---|---|---|---|---|")
    for method, r in rows.items():
        print(
            f"| {method} | {r['stall_recall']:.1f}% | {r['grip_recall']:.1f}% | "
            f"{r['push_recall']:.1f}% | {r['false_alarms']:.0f} ({r['fa_per_h']:.1f}) | "
            f"{r['p50_ms']:.0f} / {r['p95_ms']:.0f} / {r['max_ms']:.0f} |"
        )
    return rows


if __name__ == "__main__":
    bench_contact()
