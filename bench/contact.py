"""Labelled contact-detection benchmark on pure simulated arms (no transport, seeded).

``bench_contact()`` runs >= 200 scripted episodes (free motion at many speeds and step sizes,
the spec's example pose, every joint to both limits, stalls on every arm joint at several speeds,
gripping an object vs closing on air, a held joint pushed by a moving obstacle, joints dragged
by hand while unloaded; noise and feedback jitter on part of them), each labelled with the true
contact onset (the first physics step in which the joint is blocked), on every arm dynamics
family of ``contact_families.py`` (never only the simulator the detector was written
against), with the detector uncalibrated and calibrated (the calibration routine and fit run on
that family's arm). Per family it prints recall of stalls, grips and pushes, false alarms per
hour of free motion, force limits in free motion and the detection delay p50/p95 of the default
combination (the detector's own CONFIRMED state), and writes the table with a header naming the
run to ``artifacts/contact/report.md`` (``contact_report.py``: the results page is made from
it). Run: ``python -m bench --only contact``.
"""

from __future__ import annotations

import dataclasses
import math
import random
import time
from dataclasses import dataclass, field

from bench import contact_report
from bench.contact_families import families
from fleet.contact.calibration import Calibration, JointCalibration
from fleet.contact.config import METHODS, ContactConfig
from fleet.contact.detector import ContactDetector, ContactState
from fleet.contact.dynamics import SimDynamics
from fleet.contact.feed import feed_command
from fleet.contact.fit import feedback_jitter_s, fit_joint
from fleet.d1 import protocol as p
from fleet.d1.limits import JOINT_RANGE_DEG
from fleet.sim.model import SimArmModel
from fleet.sim.obstacles import Obstacle
from fleet.sim.routine import record_steps

DEFAULT = "default"
SPEC_POSE = (0.0, -60.0, 60.0, 0.0, 30.0, 0.0, 0.0)
"""The D1 spec's example target of ``1/2``."""
FORCE_LIMIT = "force limit"


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
    model_note: str = ""


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
    for mode in (0, 1):  # the spec's example pose and back
        home = [0.0] * 7
        cmds = [
            (0.5, p.SetAllAngles(SPEC_POSE, mode)),
            (8.0, p.SetAllAngles(tuple(home), mode)),
        ]
        eps.append(Episode(f"free-spec-pose-m{mode}", "free", 700 + mode, 15.0, home, cmds))
    for joint in range(7):  # every joint to both its limits, both modes
        lo, hi = JOINT_RANGE_DEG[joint]
        t, cmds = 0.5, []
        for mode in (0, 1):
            for angle in (hi, lo, 0.0):
                pose = [0.0] * 7
                pose[joint] = angle
                cmds.append((t, p.SetAllAngles(tuple(pose), mode)))
                t += (hi - lo) / 20.0 + 1.5  # the slowest plausible arm gets there
        eps.append(Episode(f"free-limits-j{joint}", "free", 710 + joint, t, [0.0] * 7, cmds))
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


def run(
    ep: Episode, config: ContactConfig, dynamics: SimDynamics, calibration: Calibration | None
) -> Outcome:
    """Play ``ep`` on an arm of ``dynamics`` and a detector; deliver feedback at the arm's rate
    with latency and jitter. Free-motion force limits are counted under ``FORCE_LIMIT``."""
    rng = random.Random(ep.seed)
    model = SimArmModel(
        angles_deg=list(ep.start), target_deg=list(ep.start), rng=rng, dynamics=dynamics
    )
    model.faults.noise_deg, model.faults.drags = ep.noise_deg, dict(ep.drags)
    if ep.obstacle is not None and ep.contact_joint is not None:
        model.faults.obstacles[ep.contact_joint] = dataclasses.replace(ep.obstacle)
    det = ContactDetector(config, calibration=calibration)
    det.on_targets(dict(enumerate(ep.start)), 1, 0.0)
    commands = list(ep.commands)
    found: dict[str, list[tuple[int, float]]] = {}
    onset: float | None = None
    period = dynamics.period_s()
    jitter = ep.jitter_s + dynamics.jitter_s
    t, reports = rng.uniform(0.0, 0.1), 0
    while t < ep.duration_s:
        while commands and commands[0][0] <= t:
            sent, command = commands.pop(0)
            model.advance(sent + 0.002)
            feed_command(det, command, sent)
            model.apply(p.encode_command(command, 1))
        model.advance(t)
        ob = model.faults.obstacles.get(ep.contact_joint) if ep.contact_joint is not None else None
        if onset is None and ob is not None and ob.met_s is not None:
            onset = ob.met_s  # the first blocked step (not the last un-hunted one)
        arrive = t + rng.uniform(0.0005, 0.003) + rng.uniform(0.0, jitter)
        if reports % 5 == 0:
            status = model.status_reports()[0]
            assert isinstance(status, p.D1Status)
            det.on_status(status.error, status.enabled, status.powered, arrive)
        joints = model.joint_report()
        assert joints is not None
        report = det.on_angles(joints.angles_deg, arrive)
        for change in report.changes:
            if change.state is ContactState.CONFIRMED:
                found.setdefault(DEFAULT, []).append((change.joint, arrive))
        for joint in report.force_limit:
            found.setdefault(FORCE_LIMIT, []).append((joint, arrive))
        reports += 1
        t += rng.uniform(*period) + rng.uniform(0.0, jitter)
    for j in range(7):
        for method, times in det.confirmations(j).items():
            found.setdefault(method, []).extend((j, s) for s in times)
    return Outcome(ep, onset, found, det.sanity.note())


def _pct(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[max(1, math.ceil(q / 100 * len(ordered))) - 1]


def score(outcomes: list[Outcome], method: str) -> dict[str, float]:
    """Recall per contact kind, false alarms (count, per hour of free motion), force limits in
    free motion, delays (ms)."""
    hits: dict[str, list[bool]] = {"stall": [], "grip": [], "push": []}
    delays: list[float] = []
    false_alarms, free_s, free_limits = 0, 0.0, 0
    for out in outcomes:
        ep, onset = out.episode, out.onset_s
        found = out.confirmations.get(method, [])
        limits = out.confirmations.get(FORCE_LIMIT, [])
        free_s += ep.duration_s if onset is None else onset
        if ep.contact_joint is None or onset is None:
            false_alarms += len(found)
            free_limits += len(limits)
            if ep.contact_joint is not None:
                hits[ep.kind].append(False)  # the obstacle was never met: a miss
            continue
        good = [s for j, s in found if j == ep.contact_joint and s >= onset]
        false_alarms += sum(1 for j, s in found if j != ep.contact_joint or s < onset)
        free_limits += sum(1 for j, s in limits if j != ep.contact_joint or s < onset)
        hits[ep.kind].append(bool(good))
        if good:
            delays.append((min(good) - onset) * 1000.0)
    row = {f"{k}_recall": 100.0 * sum(v) / len(v) if v else math.nan for k, v in hits.items()}
    row |= {
        "false_alarms": false_alarms,
        "fa_per_h": false_alarms / (free_s / 3600.0),
        "free_force_limits": free_limits,
        "p50_ms": _pct(delays, 50),
        "p95_ms": _pct(delays, 95),
        "max_ms": max(delays) if delays else math.nan,
        "free_h": free_s / 3600.0,
    }
    return row


def calibrate(
    dynamics: SimDynamics, seed: int, joints: tuple[int, ...] = tuple(range(7))
) -> Calibration:
    """Run the calibration routine on a simulated arm of ``dynamics``, joint by joint from
    where the arm stands, and fit each joint, as ``fleet calibrate`` does on a real arm (the
    family's joints are alike, but each joint's fit sees its own steps, feedback and noise)."""
    model = SimArmModel(dynamics=dynamics, rng=random.Random(seed))
    rng = random.Random(seed)
    fitted: list[JointCalibration] = []
    jitters: list[float] = []
    timing = ContactConfig().arm.timing_tolerance_s
    for joint in joints:
        records = record_steps(model, joint, rng)
        jitters.append(feedback_jitter_s(records))
        fitted.append(fit_joint(joint, records, max(timing, jitters[-1])))
    jitter = max(jitters, default=0.0)
    return Calibration("bench", 0, fitted, routine="bench", feedback_jitter_s=jitter)


def bench_contact(
    seed: int = 7, config: ContactConfig | None = None, draws: int = 4
) -> dict[str, dict[str, dict[str, float]]]:
    """Run the suite on every dynamics family, uncalibrated and calibrated; print the table
    and write it to ``artifacts/contact/report.md``.
    Returns family -> configuration -> figures (the default combination, the detector's own
    confirmed state), and ``per method`` on the simulator's default family."""
    config = config or ContactConfig()
    started = time.perf_counter()
    suite = episodes(seed)
    kinds = {
        k: sum(1 for e in suite if e.kind == k) for k in ("free", "air", "stall", "grip", "push")
    }
    print(f"contact detection: {len(suite)} episodes {kinds} per family and configuration")
    print(contact_report.HEAD)
    report = contact_report.now(seed, kinds, tuple(config.methods))
    table: list[str] = []
    rows: dict[str, dict[str, dict[str, float]]] = {}
    for k, (name, dynamics) in enumerate(families(seed, draws).items()):
        rows[name] = {}
        for label, calibration in (
            ("none", None),
            ("calibrated", calibrate(dynamics, seed + k)),
        ):
            outcomes = [run(ep, config, dynamics, calibration) for ep in suite]
            r = score(outcomes, DEFAULT)
            r["revoked"] = sum(1 for o in outcomes if "untrusted: off" in o.model_note)
            rows[name][label] = r
            if k == 0 and label == "none":
                rows["per method"] = {m: score(outcomes, m) for m in METHODS}
            table.append(contact_report.table_row(name, label, r))
            print(table[-1], flush=True)
    wall_s = time.perf_counter() - started
    report = contact_report.finished(report, wall_s)
    path = contact_report.write(contact_report.markdown(report, table))
    print(f"{wall_s:.0f} s; default = {'+'.join(config.methods)}; written: {path}")
    return rows


if __name__ == "__main__":
    bench_contact()
