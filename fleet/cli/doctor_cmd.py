"""``fleet doctor [--json]``: check the host's arm network and the fleet; exit 1 on any failure."""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

from fleet import doctor
from fleet.client import FleetClient
from fleet.runtime import inventory_from_args
from fleet.wire.session import RouterUnreachable


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``doctor``."""
    parser = sub.add_parser(
        "doctor", help="check interfaces, DDS, router, agents, feedback, clocks, versions"
    )
    add_common(parser)
    parser.add_argument("--json", action="store_true", help="one JSON object per check")
    parser.set_defaults(run=run_doctor)


def run_doctor(args: argparse.Namespace) -> int:
    """Every check, printed as found; 0 when none failed, else 1."""
    inventory = inventory_from_args(args)
    checks: list[doctor.Check] = []

    def report(found: list[doctor.Check]) -> None:
        for check in found:
            checks.append(check)
            if args.json:
                print(json.dumps(check.__dict__), flush=True)
            else:
                print("\n".join(check.lines()), flush=True)

    report(doctor.host_checks(inventory))
    endpoints = ", ".join(inventory.endpoints)
    started = time.monotonic()
    try:
        client = FleetClient(inventory, connect_timeout_s=args.connect_timeout)
    except RouterUnreachable as exc:
        fix = "start it (fleet router, or its systemd unit) or fix [zenoh] endpoints"
        report([doctor.Check(f"router {endpoints}", "fail", str(exc).split(";")[0], fix)])
        client = None
    if client is not None:
        with client:
            elapsed_ms = (time.monotonic() - started) * 1000
            report([doctor.Check(f"router {endpoints}", "ok", f"answered in {elapsed_ms:.0f} ms")])
            report(doctor.check_arms(client, inventory.arms))
            report(doctor.check_devices(client, inventory.devices))
            if any(label.startswith("g1/") for label in client.device_labels()):
                report(doctor.check_g1_services(client.device_snapshot()))
            report(doctor.check_processes(client))
            report([doctor.check_coordinator(client)])
    failed = sum(c.level == "fail" for c in checks)
    warned = sum(c.level == "warn" for c in checks)
    if not args.json:
        print(f"fleet doctor: {len(checks)} checks, {failed} failed, {warned} warnings")
    return 1 if failed else 0
