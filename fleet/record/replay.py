"""``fleet replay``: a recording back into the key space, read-only, or onto an arm.

Read-only (default): the recorded state keys (joints, status, contact) are re-published, at
their recorded pace, under another fleet name (``<fleet>-replay`` unless told): no agent serves
that prefix, and command, stop and reset keys are never published, so nothing can move. Point
a viewer at it with an inventory whose ``[fleet] name`` is the replay's.

``--onto ARM`` (drag-teach): one recorded arm's joints become a choreography, resampled at the
control rate (linear segments of 0.1 s) after a slow approach from the arm's pose; the player
checks joint and speed limits against the arm's measured pose before anything moves.
"""

from __future__ import annotations

import threading
import time

import zenoh

from fleet.choreo.script import Move, Pose, Script
from fleet.d1.limits import CONTROL_RATE_HZ, JOINT_COUNT
from fleet.record.errors import RecordError, TeachError
from fleet.record.reader import Recorded
from fleet.wire import keys, payloads
from fleet.wire import messages as m

REPLAYED_CHANNELS = (keys.JOINTS, keys.STATUS, keys.CONTACT)
"""An arm's state channels that a read-only replay re-publishes."""
REPLAYED_DEVICE_CHANNELS = (keys.STATE, keys.CONTACT, keys.LOWSTATE)
"""A device's (every kind's) state channels that a read-only replay re-publishes (a G1's
lowstate too: a live viewer of the replayed fleet poses it)."""
APPROACH_SPEED_DEG_S = 30.0
TEACH_MAX_SPEED_DEG_S = 120.0
"""A recorded motion faster than this (a hand can fling an unloaded arm) is refused on replay;
the default of hand-written scripts (90 deg/s) would refuse the arm's own mode-1 moves."""
MAX_TEACH_S = 3600.0
"""Drag-teach replays at most this much of a recording (36,000 steps at 10 Hz): a stamp far
off (a stray put, a clock step) would otherwise make the resampling loop run for years."""


def _split(key: str) -> tuple[str, str, str] | None:
    """(fleet, arm, channel) of a recorded arm key; None for anything else."""
    parsed = _parsed(key)
    if parsed is None or parsed.kind != keys.ARM or parsed.principal:
        return None
    return parsed.fleet, parsed.unit, parsed.channel


def _parsed(key: str) -> keys.Key | None:
    try:
        return keys.parse_key(key)
    except keys.KeyError_:
        return None


def _replayed(key: str) -> keys.Key | None:
    """The parsed key if a read-only replay re-publishes it: state, never a command or stop."""
    parsed = _parsed(key)
    if parsed is None or parsed.principal:
        return None
    if parsed.kind == keys.ARM and parsed.channel in REPLAYED_CHANNELS:
        return parsed
    if parsed.kind in keys.DEVICE_KINDS and parsed.channel in REPLAYED_DEVICE_CHANNELS:
        return parsed
    return None


def recorded_joints(
    messages: list[Recorded], arm: str | None = None, source: str = "<recording>"
) -> tuple[str, list[m.Joints]]:
    """The joints samples of ``arm`` (default: the only arm with joints in the file). A joints
    payload that does not decode is a damaged file (``fleet record`` writes none): RecordError."""
    arms: dict[str, list[m.Joints]] = {}
    for index, message in enumerate(messages):
        split = _split(message.key)
        if split is not None and split[2] == keys.JOINTS:
            try:
                sample = payloads.JOINTS.decode(message.data)
            except payloads.PayloadError as exc:
                raise RecordError(f"{source}: message {index} ({message.key}): {exc}") from None
            arms.setdefault(split[1], []).append(sample)
    if arm is None:
        if len(arms) != 1:
            raise RecordError(f"{source}: the recording has joints of {sorted(arms)}: pass --arm")
        arm = next(iter(arms))
    if arm not in arms:
        raise RecordError(f"{source}: no joints of {arm!r} (it has {sorted(arms)})")
    return arm, arms[arm]


def usable_samples(samples: list[m.Joints]) -> tuple[list[m.Joints], int]:
    """The samples drag-teach can follow, and how many it skipped: each kept sample has seven
    angles and a stamp later than the one kept before it. Out-of-order or repeated stamps (an
    agent restarted with its clock stepped back, a stray put on the joints key) are skipped, not
    sorted in: a sample from elsewhere in time would be a jump in the motion."""
    kept: list[m.Joints] = []
    for sample in samples:
        if len(sample.angles_deg) != JOINT_COUNT:
            continue
        if kept and sample.stamp_ns <= kept[-1].stamp_ns:
            continue
        kept.append(sample)
    return kept, len(samples) - len(kept)


def teach_script(samples: list[m.Joints], onto: str, start_pose: Pose, source: str) -> Script:
    """The drag-teach choreography: approach the first sample, then follow the recording
    (resampled at the control rate). Unusable samples are skipped (``usable_samples``); more
    than ``MAX_TEACH_S`` of recording, or fewer than two samples, is a TeachError."""
    samples, _skipped = usable_samples(samples)
    if len(samples) < 2:
        raise TeachError(f"{source}: fewer than two usable joint samples: nothing to replay")
    t0 = samples[0].stamp_ns
    span_s = (samples[-1].stamp_ns - t0) / 1e9
    if span_s > MAX_TEACH_S:
        raise TeachError(
            f"{source}: the joint samples span {span_s:.0f} s (stamps {t0} .. "
            f"{samples[-1].stamp_ns}); drag-teach replays at most {MAX_TEACH_S:.0f} s: "
            "record a shorter take"
        )
    times = [(s.stamp_ns - t0) / 1e9 for s in samples]
    period = 1.0 / CONTROL_RATE_HZ
    steps: list[Move] = []
    first = tuple(samples[0].angles_deg)
    distance = max(abs(a - b) for a, b in zip(first, start_pose))
    approach = max(1.0, 1.5 * distance / APPROACH_SPEED_DEG_S)
    steps.append(Move(approach, "ease_in_out", {onto: first}, "approach"))
    index = 0
    for k in range(1, int(span_s * CONTROL_RATE_HZ + 1e-6) + 1):  # at most 36,000 steps
        t = k * period
        while index + 2 < len(times) and times[index + 1] < t:  # bounded by len(times)
            index += 1
        a, b = samples[index], samples[index + 1]
        span = max(times[index + 1] - times[index], 1e-6)
        u = min(1.0, max(0.0, (t - times[index]) / span))
        pose = tuple(x + (y - x) * u for x, y in zip(a.angles_deg, b.angles_deg))
        steps.append(Move(period, "linear", {onto: pose}, f"replay {t:.1f} s"))
    last = tuple(samples[-1].angles_deg)
    if steps[-1].poses[onto] != last:
        # The recording rarely ends on a control period: its last pose is where the take
        # ended (the arm ended 1.5 deg or more away from it when the take ended mid-motion).
        steps.append(Move(period, "linear", {onto: last}, f"replay end {span_s:.2f} s"))
    return Script(
        name=f"replay of {source}",
        arms=(onto,),
        steps=tuple(steps),
        max_speed_deg_s=TEACH_MAX_SPEED_DEG_S,
        source=source,
    )


def replay_read_only(
    session: zenoh.Session,
    messages: list[Recorded],
    fleet: str,
    stop: threading.Event,
    speed: float = 1.0,
) -> int:
    """Re-publish the state keys of every kind (arms' joints, status and contacts, devices'
    state and contacts, a G1's lowstate) under ``fleet/<fleet>/...`` at the recorded pace;
    returns the number of samples published. Never publishes a command, stop or reset key."""
    space = keys.KeySpace(fleet)
    state = [(r, p) for r in messages if (p := _replayed(r.key)) is not None]
    if not state:
        return 0
    start_log, start = state[0][0].log_time_ns, time.monotonic()
    published = 0
    for record, parsed in state:
        due = start + (record.log_time_ns - start_log) / 1e9 / speed
        if stop.wait(max(0.0, due - time.monotonic())):
            break
        if parsed.kind == keys.ARM:
            key = space.arm(parsed.unit, parsed.channel)
        else:
            key = space.device(parsed.kind, parsed.unit, parsed.channel)
        session.put(key, record.data, encoding=zenoh.Encoding.APPLICATION_JSON)
        published += 1
    return published
