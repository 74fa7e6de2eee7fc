"""``fleet status`` (table, ``--json``, ``--watch``) and ``fleet schema``."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any

import msgspec

from fleet.cli.screen import Screen
from fleet.client import FleetClient
from fleet.devices import kinds
from fleet.inventory import Inventory
from fleet.runtime import inventory_from_args, shutdown_event
from fleet.wire import messages as m
from fleet.wire import payloads

Snapshot = dict[str, tuple[m.ArmStatus | None, m.Joints | None]]


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``status`` and ``schema``."""
    status = sub.add_parser(
        "status",
        help="one line per arm: agent, link, power, contact, calibration (calib NONE or PART: run "
        "fleet calibrate), angles",
    )
    add_common(status)
    status.add_argument("--json", action="store_true", help="machine-readable output")
    status.add_argument("--watch", action="store_true", help="refresh every second until Ctrl-C")
    status.set_defaults(run=run_status)

    schema = sub.add_parser("schema", help="print the JSON Schema of every key-space payload")
    schema.add_argument("--log-level", default="WARNING")
    schema.set_defaults(run=run_schema)


def _flag(value: bool | None, yes: str, no: str) -> str:
    return "?" if value is None else (yes if value else no)


def _contact(state: m.FleetState | None, arm: str) -> str:
    """From the coordinator's state, which aggregates the agents' contact reports: ``?``
    without a coordinator, ``no`` for an arm that never reported one."""
    summary = None if state is None else state.arms.get(arm)
    if summary is None:
        return "?"
    return "YES" if summary.contact else "no"


MODEL = {
    "calibrated": "ok",
    "partial": "PART",
    "uncalibrated": "NONE",
    "untrusted": "OFF",
    None: "-",
}
"""The ``calib`` column: the contact detector's model of the arm (``fleet calibrate``)."""


def status_lines(
    inventory: Inventory,
    snapshot: Snapshot,
    alive: set[str],
    state: m.FleetState | None = None,
    width: int | None = None,
) -> list[str]:
    """A header and one fixed-width line per arm (the stop's reason under a stopped arm). With
    ``width`` (a terminal's) narrower than a whole line, each arm's angles fold onto a line of
    their own below it."""
    head = (
        f"{'arm':<8} {'agent':<7} {'link':<6} {'power':<6} {'torque':<7} {'error':<6} "
        f"{'stop':<5} {'contact':<7} {'calib':<5} {'age_s':>6}"
    )
    rows: list[tuple[str, str]] = []
    reasons: dict[str, str] = {}
    for arm in inventory.arms:
        status, joints = snapshot.get(arm, (None, None))
        agent = "up" if arm in alive else "DOWN"
        contact = _contact(state, arm)
        if status is None:
            rows.append(
                (
                    arm,
                    f"{arm:<8} {agent:<7} {'-':<6} {'-':<6} {'-':<7} {'-':<6} {'-':<5} "
                    f"{contact:<7} {'-':<5} {'-':>6}",
                )
            )
            continue
        age = "-" if status.feedback_age_s is None else f"{status.feedback_age_s:.2f}"
        rows.append(
            (
                arm,
                f"{arm:<8} {agent:<7} {status.link:<6} {_flag(status.powered, 'on', 'off'):<6} "
                f"{_flag(status.enabled, 'on', 'free'):<7} {_flag(status.error, 'ERROR', 'ok'):<6} "
                f"{'YES' if status.estopped else 'no':<5} {contact:<7} "
                f"{MODEL[status.contact_model]:<5} {age:>6}",
            )
        )
        if status.estopped and status.stop_reason:
            reasons[arm] = f"{'':<8} {status.stop_reason}"
    wide = " ".join(["-000.0"] * 7)
    fold = width is not None and len(head) + 2 + len(wide) + 1 >= width
    lines = [head if fold else f"{head}  angles_deg"]
    for arm, row in rows:
        joints = snapshot.get(arm, (None, None))[1]
        if fold:
            lines.append(row)
            if joints is not None:
                lines.append(f"{'':<8} " + " ".join(f"{a:.1f}" for a in joints.angles_deg))
        else:
            angles = "-" if joints is None else " ".join(f"{a:7.1f}" for a in joints.angles_deg)
            lines.append(f"{row}  {angles}")
        if arm in reasons:
            lines.append(reasons[arm])
    return lines


def device_lines(inventory: Inventory, states: dict[str, Any]) -> list[str]:
    """One line per device (gripper opening, G1 FSM), after the arms."""
    if not states:
        return []
    lines = [f"{'device':<16} {'link':<6} {'stop':<5} state"]
    for label, state in states.items():
        if state is None:
            lines.append(f"{label:<16} {'-':<6} {'-':<5} no state (is its card's agent up?)")
            continue
        kind = kinds()[label.partition("/")[0]]
        stop = "YES" if state.estopped else "no"
        lines.append(f"{label:<16} {state.link:<6} {stop:<5} {kind.summary(state)}")
        if state.estopped and state.stop_reason:
            lines.append(f"{'':<16} {state.stop_reason}")
    return lines


def _as_json(snapshot: Snapshot, alive: set[str], devices: dict[str, Any] | None = None) -> str:
    """Arms by id (as before the devices), then devices by ``<kind>/<id>`` (a ``/`` no arm id
    has, so the two never collide): ``{"kind", "state"}`` (``state`` null: none heard)."""
    out: dict[str, Any] = {
        arm: {
            "agent": arm in alive,
            "status": None if status is None else msgspec.to_builtins(status),
            "joints": None if joints is None else msgspec.to_builtins(joints),
        }
        for arm, (status, joints) in snapshot.items()
    }
    for label, state in (devices or {}).items():
        out[label] = {
            "kind": label.partition("/")[0],
            "state": None if state is None else msgspec.to_builtins(state),
        }
    return json.dumps(out, indent=2)


def run_status(args: argparse.Namespace) -> int:
    """Print the fleet's status; exit 3 when any arm's agent is down or its link is not ok."""
    inventory = inventory_from_args(args)
    stop = shutdown_event(quiet=True)
    healthy = True
    screen = Screen(sys.stdout, tty=args.watch and sys.stdout.isatty())
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        while True:
            snapshot = client.snapshot()
            alive = client.agents_alive()
            state = client.fleet_state()
            devices = client.device_snapshot()
            healthy = all(
                arm in alive and status is not None and status.link == "ok"
                for arm, (status, _j) in snapshot.items()
            ) and all(d is not None and d.link == "ok" for d in devices.values())
            if args.json:
                print(_as_json(snapshot, alive, devices), flush=True)
            else:
                # --watch redraws in place, laid out and cut to the terminal's width
                width = screen.width() if screen.tty else None
                lines = status_lines(inventory, snapshot, alive, state, width)
                lines += device_lines(inventory, devices)
                screen.draw(lines)
            if not args.watch or stop.wait(1.0):
                break
    return 0 if healthy else 3


def run_schema(_args: argparse.Namespace) -> int:
    """JSON Schema of every payload, keyed by the key it travels on."""
    channels = list(payloads.CHANNELS.values())
    types = [c.payload.struct for c in channels]
    schemas, components = msgspec.json.schema_components(types, ref_template="#/$defs/{name}")
    out = {"keys": {c.key: s for c, s in zip(channels, schemas, strict=True)}, "$defs": components}
    print(json.dumps(out, indent=2))
    return 0
