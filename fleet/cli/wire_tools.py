"""``fleet echo``, ``hz``, ``diag`` and ``sim fault``: the wire, seen from a shell.

Each subscribes with a callback that only queues (bounded; overflow counted and reported) and
prints from the main thread. Every loop ends on Ctrl-C, ``--for-s`` or ``--count``.
"""

from __future__ import annotations

import argparse
import json
import queue
import shutil
import sys
import textwrap
import time
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from fleet import tap
from fleet.client import FleetClient
from fleet.devices import kind_of
from fleet.inventory import Inventory
from fleet.runtime import inventory_from_args, shutdown_event
from fleet.sim import faults
from fleet.wire import keys, payloads
from fleet.wire import messages as m

INBOX = 10_000


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``echo``, ``hz``, ``diag`` and ``sim fault`` (under ``fleet sim``)."""
    echo = sub.add_parser("echo", help="print each sample on KEY_EXPR, decoded (one per line)")
    add_common(echo)
    echo.add_argument("key_expr", metavar="KEY_EXPR", help="e.g. arm/a1/joints, arm/*/status, **")
    echo.add_argument("--json", action="store_true", help="one JSON object per line")
    _add_bounds(echo)
    echo.set_defaults(run=run_echo)

    hz = sub.add_parser("hz", help="rate, jitter and gaps of each key on KEY_EXPR")
    add_common(hz)
    hz.add_argument("key_expr", metavar="KEY_EXPR", help="e.g. arm/*/joints")
    hz.add_argument("--window", type=int, default=100, help="intervals averaged (default 100)")
    hz.add_argument("--json", action="store_true", help="one JSON object per key and report")
    _add_bounds(hz)
    hz.set_defaults(run=run_hz)

    diag = sub.add_parser("diag", help="the agents' diag counters as a table (arms and devices)")
    add_common(diag)
    diag.add_argument("arm", nargs="?", help="one arm or device (default: every arm and device)")
    diag.add_argument("--watch", action="store_true", help="refresh every second until Ctrl-C")
    diag.add_argument("--json", action="store_true", help="machine-readable output")
    diag.set_defaults(run=run_diag)

    # `fleet sim fault ...`: a subcommand of `fleet sim` (registered by processes.py before us);
    # `fleet sim` alone still runs the simulator.
    sim = sub.choices["sim"]
    sim_sub = sim.add_subparsers(dest="sim_command", metavar="fault")
    fault = sim_sub.add_parser("fault", help="inject a fault into a simulated arm")
    add_common(fault)
    fault.add_argument("arm", help="the simulated arm")
    fault.add_argument("op", choices=sorted(FAULT_OPS), help="the fault")
    for flag, (field, kind, text) in FAULT_OPTIONS.items():
        if kind is bool:
            fault.add_argument(flag, dest=field, action="store_const", const=False, help=text)
        else:
            fault.add_argument(flag, dest=field, type=kind, default=None, help=text)
    fault.set_defaults(run=run_fault)


def _add_bounds(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--for-s", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--count", type=int, default=None, help="stop after N samples")


class _Inbox:
    """Samples from the Zenoh thread: (key, bytes, received_ns, monotonic s); bounded."""

    def __init__(self) -> None:
        self.queue: queue.Queue[tuple[str, bytes, int, float]] = queue.Queue(INBOX)
        self.dropped = 0

    def __call__(self, sample: zenoh.Sample) -> None:
        try:
            item = (str(sample.key_expr), sample.payload.to_bytes(), time.time_ns())
            self.queue.put_nowait((*item, time.monotonic()))
        except queue.Full:
            self.dropped += 1


def _loop(
    args: argparse.Namespace,
    on_item: Callable[[tuple[str, bytes, int, float]], None],
    on_tick: Callable[[], None] | None = None,
) -> tuple[int, _Inbox]:
    """Subscribe to KEY_EXPR and feed ``on_item`` until Ctrl-C, --for-s or --count."""
    inventory = inventory_from_args(args)
    keyspace = keys.KeySpace(inventory.fleet)
    expr = tap.key_expr(keyspace, args.key_expr)
    stop = shutdown_event(quiet=True)
    inbox = _Inbox()
    deadline = None if args.for_s is None else time.monotonic() + args.for_s
    seen = 0
    next_tick = time.monotonic() + 1.0
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        subscriber = client.session.declare_subscriber(expr, inbox)
        try:
            while not stop.is_set() and (args.count is None or seen < args.count):
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                if on_tick is not None and now >= next_tick:
                    next_tick = now + 1.0
                    on_tick()
                try:
                    item = inbox.queue.get(timeout=0.1)
                except queue.Empty:
                    continue
                seen += 1
                on_item(item)
        finally:
            subscriber.undeclare()
    return seen, inbox


def run_echo(args: argparse.Namespace) -> int:
    """Print every sample on KEY_EXPR; a summary on stderr at the end."""
    keyspace = keys.KeySpace(inventory_from_args(args).fleet)
    bad = [0]

    def show(item: tuple[str, bytes, int, float]) -> None:
        key, data, stamp_ns, _now = item
        sample = tap.decode_sample(keyspace, key, data)
        bad[0] += sample.error is not None
        print(tap.format_line(sample, stamp_ns, args.json), flush=True)

    seen, inbox = _loop(args, show)
    print(
        f"fleet echo: {seen} samples, {bad[0]} undecodable, {inbox.dropped} dropped "
        "(printing fell behind)",
        file=sys.stderr,
    )
    return 0


def run_hz(args: argparse.Namespace) -> int:
    """Per key: average rate, min/max interval, std dev (jitter), gaps; printed every second."""
    windows: dict[str, tap.RateWindow] = {}

    def add(item: tuple[str, bytes, int, float]) -> None:
        key, _data, _stamp, now = item
        if key not in windows and len(windows) < 1000:
            windows[key] = tap.RateWindow(args.window)
        if key in windows:
            windows[key].add(now)

    def report() -> None:
        if not windows:
            print("fleet hz: no samples yet", flush=True)
        for key in sorted(windows):
            stats = windows[key].stats()
            line = json.dumps({"key": key, **stats}) if args.json else tap.format_rate(key, stats)
            print(line, flush=True)

    _seen, _inbox = _loop(args, add, report)
    report()
    return 0 if windows else 3


# ----------------------------------------------------------------------------- diag

DIAG_COLUMNS = (
    ("link", "link", 5),
    ("relayed", "relayed", 8),
    ("malformed", "malf", 5),
    ("unknown_messages", "unkn", 5),
    ("rejected", "refused", 7),
    ("commands", "cmds", 6),
    ("ack_timeouts", "ack_to", 6),
    ("acks_unmatched", "unmatch", 7),
    ("acks_ignored", "ignored", 7),
    ("acks_foreign", "foreign", 7),
    ("feedback_rate_hz", "rate_hz", 7),
    ("last_feedback_age_s", "age_s", 6),
    ("bad_payloads", "badpl", 5),
    ("busy", "busy", 5),
    ("dropped_events", "dropped", 7),
    ("write_failures", "wfail", 5),
)


def diag_lines(units: list[str], diags: dict[str, m.Diag], columns: int | None = None) -> list[str]:
    """A header and one line per arm or device (``-`` for one whose agent published no diag),
    and the last error under one that has one, whole, wrapped at word boundaries to
    ``columns`` (default: the terminal's width; issue 26: it was cut at 100 characters
    mid-sentence). Devices are named ``<kind>/<id>``."""
    if columns is None:
        columns = shutil.get_terminal_size((100, 24)).columns
    width = max([8, *(len(u) + 1 for u in units)])
    header = f"{'unit':<{width}} " + " ".join(f"{title:>{w}}" for _f, title, w in DIAG_COLUMNS)
    lines = [header]
    for unit in units:
        diag = diags.get(unit)
        if diag is None:
            cells = " ".join(f"{'-':>{w}}" for _f, _t, w in DIAG_COLUMNS)
            lines.append(f"{unit:<{width}} {cells}")
            continue
        texts = []
        for field, _title, w in DIAG_COLUMNS:
            value = getattr(diag, field)
            text = "-" if value is None else f"{value:.1f}" if isinstance(value, float) else value
            texts.append(f"{text!s:>{w}}")
        lines.append(f"{unit:<{width}} " + " ".join(texts))
        if diag.last_error:
            lead = f"{'':<{width}} last error: "
            lines += textwrap.wrap(
                diag.last_error,
                width=max(40, columns - 1),
                initial_indent=lead,
                subsequent_indent=" " * len(lead),
                break_on_hyphens=False,
            )
    return lines


def diag_units(inventory: Inventory, which: str | None) -> list[str]:
    """Every arm id and device ``<kind>/<id>`` of the inventory, or the one ``which`` names
    (an arm id, a device id or ``<kind>/<id>``); InventoryError for an unknown one."""
    devices = {f"{kind_of(d).key}/{d.id}": d.id for d in inventory.devices.values()}
    if which is None:
        return [*inventory.arms, *devices]
    if which in inventory.arms:
        return [which]
    for label, device in devices.items():
        if which in (label, device):
            return [label]
    inventory.arm(which)  # raises, naming the known arms
    return []


def _diag_key_label(space: keys.KeySpace, key: str) -> str | None:
    """``a1`` for an arm's diag key, ``gripper/gl`` for a device's; None for anything else."""
    try:
        parsed = space.parse_key(key)
    except keys.KeyError_:
        return None
    if parsed.channel != keys.DIAG or parsed.kind == keys.FLEET_LEVEL:
        return None
    return parsed.unit if parsed.kind == keys.ARM else f"{parsed.kind}/{parsed.unit}"


def _collect_diag(client: FleetClient, units: list[str], wait_s: float) -> dict[str, m.Diag]:
    inbox = _Inbox()
    wanted = [client.keys.all_arms(keys.DIAG)]
    wanted += [client.keys.device(k, "*", keys.DIAG) for k in keys.DEVICE_KINDS]
    subscribers = [client.session.declare_subscriber(key, inbox) for key in wanted]
    got: dict[str, m.Diag] = {}
    deadline = time.monotonic() + wait_s
    try:
        while not all(u in got for u in units) and time.monotonic() < deadline:
            try:
                key, data, _stamp, _now = inbox.queue.get(timeout=0.1)
            except queue.Empty:
                continue
            label = _diag_key_label(client.keys, key)
            try:
                if label is not None:
                    got[label] = payloads.DIAG.decode(data)
            except payloads.PayloadError:
                continue
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()
    return got


def run_diag(args: argparse.Namespace) -> int:
    """The diag counters (published at 1 Hz) of every arm and device, or of one; exit 3 when
    one is missing (its agent down, or a device agent that publishes none)."""
    inventory = inventory_from_args(args)
    units = diag_units(inventory, args.arm)
    stop = shutdown_event(quiet=True)
    complete = False
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        printed = 0
        while True:
            diags = _collect_diag(client, units, wait_s=1.6)
            complete = all(u in diags for u in units)
            if args.json:
                out = {u: msgspec.to_builtins(diags[u]) if u in diags else None for u in units}
                print(json.dumps(out), flush=True)
            else:
                lines = diag_lines(units, diags)
                if printed and sys.stdout.isatty():
                    print(f"\033[{printed}F\033[J", end="")
                print("\n".join(lines), flush=True)
                printed = len(lines)
            if not args.watch or stop.wait(0.2):
                break
    return 0 if complete else 3


# ----------------------------------------------------------------------------- sim fault

FAULT_OPS: dict[str, type[Any]] = {
    cls.__struct_config__.tag: cls  # type: ignore[attr-defined]
    for cls in faults.Fault.__args__  # type: ignore[attr-defined]
}
FAULT_OPTIONS: dict[str, tuple[str, Any, str]] = {
    "--joint": ("joint", int, "joint 0..6 (6: gripper)"),
    "--angle": ("angle_deg", float, "angle in degrees (stall, drag, obstacle)"),
    "--value": ("value", int, "error_status: the abnormal value to report (e.g. 132)"),
    "--speed": ("speed_deg_s", float, "drag or obstacle speed, deg/s"),
    "--compliance": ("compliance", float, "obstacle or gripped object: 0 rigid .. 1"),
    "--hunting-deg": ("hunting_deg", float, "obstacle: servo hunting amplitude"),
    "--hunting-hz": ("hunting_hz", float, "obstacle: servo hunting frequency"),
    "--to": ("to_deg", float, "obstacle: where a moving obstacle goes"),
    "--error-after": ("error_after_s", float, "obstacle: error_status after pushing this long"),
    "--width": ("width_deg", float, "grip_object: width the gripper cannot close below"),
    "--noise-deg": ("noise_deg", float, "noise: angle noise"),
    "--jitter-s": ("jitter_s", float, "noise: feedback period jitter"),
    "--off": (
        "_off",
        bool,
        "turn the fault off (motor_offline, error_status, drop_feedback, mute_acks)",
    ),
}
_SWITCH = {
    "motor_offline": "offline",
    "error_status": "error",
    "drop_feedback": "on",
    "mute_acks": "on",
}


def fault_request(op: str, options: dict[str, Any]) -> Any:
    """The fault Struct for ``op`` and the given options (None values left out); ValueError
    naming an option the fault does not take, or a missing or bad field."""
    cls = FAULT_OPS[op]
    fields = {f.name for f in msgspec.structs.fields(cls)}
    request: dict[str, Any] = {"op": op}
    for flag, (field, _kind, _text) in FAULT_OPTIONS.items():
        value = options.get(field)
        if value is None:
            continue
        if field == "_off":
            if op not in _SWITCH:
                raise ValueError(f"{op} has no --off")
            request[_SWITCH[op]] = False
            continue
        if field not in fields:
            takes = [f for f, (name, _k, _t) in FAULT_OPTIONS.items() if name in fields]
            raise ValueError(f"{op} takes no {flag} (it takes: {', '.join(takes) or 'nothing'})")
        request[field] = value
    try:
        return msgspec.convert(request, faults.Fault)
    except msgspec.ValidationError as exc:
        raise ValueError(f"{op}: {exc}") from None


def run_fault(args: argparse.Namespace) -> int:
    """Send one fault to the simulator; 0 applied, 1 refused, 2 bad options, 3 no simulator."""
    inventory = inventory_from_args(args)
    arm = inventory.arm(args.arm).id
    try:
        request = fault_request(args.op, vars(args))
    except ValueError as exc:
        print(f"fleet sim fault: {exc}", file=sys.stderr)
        return 2
    with FleetClient(inventory, connect_timeout_s=args.connect_timeout) as client:
        key = client.keys.arm(arm, keys.SIM_FAULT)
        for reply in client.ask(key, m.encode(request), 3.0):
            if reply.ok is None:
                continue
            try:
                answer = msgspec.json.decode(reply.ok.payload.to_bytes(), type=faults.FaultReply)
            except (msgspec.DecodeError, UnicodeDecodeError, RecursionError) as exc:
                print(f"fleet sim fault: unreadable reply: {exc}", file=sys.stderr)
                return 1
            if answer.ok:
                print(f"{arm}: {args.op} applied")
                return 0
            print(f"fleet sim fault: {arm}: {answer.error}", file=sys.stderr)
            return 1
    print(
        f"fleet sim fault: no simulator answered on {key}; is `fleet sim` running, and is "
        f"{arm} simulated?",
        file=sys.stderr,
    )
    return 3
