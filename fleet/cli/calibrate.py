"""``fleet calibrate ARM [--joint J]``: measure how each joint follows its target, per
smoothing mode, and write the arm's calibration file (the inventory names it) for the contact
detector's model (method 5). Without it the detector trusts no model of the arm.

The routine (``fleet/contact/fit.py``): joint by joint, from where the arm stands, steps of 10,
40 and 80 deg towards the middle of the joint's range and back (2 deg inside the limits), in
mode 1 then mode 0; each step is waited out until the joint is still on its target. The arm is
held under this client's lease. It stops at once, holds the arm and writes nothing when a step
does not arrive (the joint stands still more than 2 deg short: an obstacle), when the agent
confirms a contact, when a command fails, or on Ctrl-C (exit 130). Keep the arm's
surroundings clear of the sweep.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Callable

import zenoh

from fleet.cli.interrupt import EXIT_BOUND_S, EXIT_INTERRUPTED, Interrupted, hold_what_moved
from fleet.client import FleetClient, default_source
from fleet.contact.calibration import (
    Calibration,
    CalibrationError,
    JointCalibration,
    load_calibration,
    merge,
    save_calibration,
)
from fleet.contact.dynamics import ModeDynamics
from fleet.contact.fit import (
    SETTLE_TOLERANCE_DEG,
    STALL_SHORT_DEG,
    StepRecord,
    feedback_jitter_s,
    fit_joint,
    plan,
)
from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG
from fleet.runtime import inventory_from_args, shutdown_event
from fleet.wire import keys, payloads
from fleet.wire import messages as m

STEP_TIMEOUT_S = 8.0
STILL_S = 0.5
"""A joint whose angle changed less than 0.2 deg over this long is still."""


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``calibrate``."""
    parser = sub.add_parser(
        "calibrate",
        help="measure an arm's joint response (slow steps) for contact detection",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_common(parser)
    parser.add_argument("arm", help="arm id")
    parser.add_argument("--joint", type=int, choices=range(JOINT_COUNT), help="one joint only")
    parser.set_defaults(run=run_calibrate)


class _Recorder:
    """The arm's joint reports (receive time, angles) and whether the agent confirmed a
    contact; the Zenoh callbacks only append under a lock."""

    def __init__(self, client: FleetClient, arm: str) -> None:
        self._lock = threading.Lock()
        self.samples: list[tuple[float, tuple[float, ...]]] = []  # guarded by _lock
        self.contact: str | None = None
        self._subs = [
            client.session.declare_subscriber(client.keys.arm(arm, keys.JOINTS), self._joints),
            client.session.declare_subscriber(client.keys.arm(arm, keys.CONTACT), self._contact),
        ]

    def _joints(self, sample: zenoh.Sample) -> None:
        try:
            joints = payloads.JOINTS.decode(sample.payload.to_bytes())
        except payloads.PayloadError:
            return
        with self._lock:
            if len(self.samples) < 100_000:
                self.samples.append((time.monotonic(), tuple(joints.angles_deg)))

    def _contact(self, sample: zenoh.Sample) -> None:
        try:
            event = payloads.CONTACT.decode(sample.payload.to_bytes())
        except payloads.PayloadError:
            return
        if event.state == "confirmed":
            self.contact = f"contact confirmed on joint {event.joint} ({event.method})"

    def since(self, start_s: float) -> list[tuple[float, tuple[float, ...]]]:
        """The reports received after ``start_s``."""
        with self._lock:
            return [s for s in self.samples if s[0] > start_s]

    def latest(self) -> tuple[float, ...] | None:
        """The newest angles, None before the first report."""
        with self._lock:
            return self.samples[-1][1] if self.samples else None

    def close(self) -> None:
        """Undeclare the subscribers."""
        for sub in self._subs:
            sub.undeclare()


def _wait_step(
    rec: _Recorder, joint: int, target: float, sent_s: float, stop: threading.Event
) -> str | None:
    """Wait until ``joint`` is still on ``target``; the reason to stop otherwise. Interrupted
    when ``stop`` (Ctrl-C) is set."""
    deadline = sent_s + STEP_TIMEOUT_S
    while time.monotonic() < deadline:
        if stop.wait(0.05):
            raise Interrupted
        if rec.contact is not None:
            return rec.contact
        recent = [(t, a[joint]) for t, a in rec.since(sent_s)]
        window = [a for t, a in recent if t >= time.monotonic() - STILL_S]
        if not recent or recent[0][0] > time.monotonic() - STILL_S or len(window) < 2:
            continue
        still = max(window) - min(window) < 0.2
        off = abs(window[-1] - target)
        if still and off < SETTLE_TOLERANCE_DEG:
            return None
        if still and off > STALL_SHORT_DEG and time.monotonic() - sent_s > 1.0:
            return (
                f"joint {joint} stopped at {window[-1]:.1f} deg, {off:.1f} deg short of "
                f"{target:.1f}: an obstacle?"
            )
    return f"joint {joint} did not settle on {target:.1f} deg within {STEP_TIMEOUT_S:.0f} s"


def _calibrate_joint(
    client: FleetClient,
    rec: _Recorder,
    arm: str,
    joint: int,
    owner: str,
    jitter: list[float],
    timing_s: float,
    stop: threading.Event,
) -> JointCalibration | str:
    """Run the steps of ``joint`` and fit them; or the reason the routine stopped.
    ``timing_s``: the arm's contact ``timing_tolerance_s`` (the fit's error beyond it).
    Interrupted when ``stop`` (Ctrl-C) is set."""
    pose = rec.latest()
    assert pose is not None
    records: list[StepRecord] = []
    for mode, target in plan(pose[joint], JOINT_RANGE_DEG[joint]):
        now_pose = rec.latest() or pose
        command_pose = list(pose)
        command_pose[joint] = target
        sent = time.monotonic()
        reply = client.command(
            arm, m.MoveJoints(angles_deg=command_pose, mode=mode, owner=owner, takeover=True)
        )
        if not reply.ok:
            why = reply.error.message if reply.error else "no reply"
            return f"the step of joint {joint} to {target:.1f} deg failed: {why}"
        problem = _wait_step(rec, joint, target, sent, stop)
        if problem is not None:
            return problem
        samples = [(t, a[joint]) for t, a in rec.since(sent)]
        records.append(StepRecord(mode, sent, now_pose[joint], target, samples))
    jitter.append(feedback_jitter_s(records))
    return fit_joint(joint, records, max(timing_s, jitter[-1]))


def _describe(c: JointCalibration) -> str:
    def mode(d: ModeDynamics) -> str:
        servo = f", servo {d.servo_hz:.1f} Hz {d.overshoot:.0%}" if d.servo_hz else ""
        return f"{d.rate_deg_s:.0f} deg/s, lag {d.lag_s:.3f} s, dead {d.dead_s:.3f} s{servo}"

    fit = f"fit {c.rms_deg} deg RMS, {c.error_deg()} beyond report timing"
    return f"joint {c.joint}: mode 1 {mode(c.mode1)}; mode 0 {mode(c.mode0)}; {fit}"


def run_calibrate(args: argparse.Namespace) -> int:
    """Run the routine on ``args.arm``; exit 1 when it stopped (nothing written)."""
    inventory = inventory_from_args(args)
    timing_s = inventory.arm(args.arm).contact.arm.timing_tolerance_s
    path = inventory.calibration_path(args.arm)
    joints = [args.joint] if args.joint is not None else list(range(JOINT_COUNT))
    owner = default_source()
    fitted: list[JointCalibration] = []
    jitters: list[float] = []
    # Ctrl-C: hold the arm, write nothing (below).
    stop = shutdown_event(quiet=True, bound_s=EXIT_BOUND_S)
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        rec = _Recorder(client, args.arm)
        try:
            deadline = time.monotonic() + 5.0
            while rec.latest() is None and time.monotonic() < deadline:
                if stop.wait(0.05):
                    return EXIT_INTERRUPTED  # nothing was sent yet
            if rec.latest() is None:
                print(f"fleet calibrate: no joint reports from arm {args.arm!r} within 5 s")
                return 3
            for joint in joints:
                print(f"calibrating joint {joint} ...", flush=True)
                try:
                    result = _calibrate_joint(
                        client, rec, args.arm, joint, owner, jitters, timing_s, stop
                    )
                except Interrupted:
                    code = hold_what_moved(client, [args.arm], owner, "fleet calibrate")
                    print("nothing was written; run it again to calibrate")
                    return code
                if isinstance(result, str):
                    client.command(args.arm, m.Hold(owner=owner, takeover=True))
                    print(f"fleet calibrate: STOPPED, the arm holds its pose: {result}")
                    print("nothing was written; clear the way and run it again")
                    return 1
                fitted.append(result)
                print(_describe(result), flush=True)
        finally:
            rec.close()
    try:
        old = load_calibration(path)
    except CalibrationError:
        old = None  # replaced by the new one
    routine = "steps 10/40/80 deg towards mid-range and back, mode 1 then 0"
    jitter = max(jitters + [0.0 if old is None else old.feedback_jitter_s])
    new = Calibration(args.arm, time.time_ns(), fitted, routine=routine, feedback_jitter_s=jitter)
    save_calibration(path, merge(old, new))
    print(f"saved {path}; the agent loads it within a second")
    return 0
