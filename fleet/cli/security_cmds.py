"""``fleet certs`` (the fleet's CA and a certificate per principal) and ``fleet acl`` (the
router's access control generated from the inventory, to review before deploying it)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable

from fleet.runtime import inventory_from_args


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``certs`` and ``acl``."""
    certs = sub.add_parser(
        "certs", help="make the fleet's CA and a certificate per principal (mutual TLS)"
    )
    add_common(certs)
    certs.add_argument(
        "--out", default=None, help="directory (default: the inventory's [security] certs)"
    )
    certs.add_argument("--days", type=int, default=365, help="validity (default 365 days)")
    certs.add_argument(
        "--force", action="store_true", help="a new CA and new certificates for everyone"
    )
    certs.set_defaults(run=run_certs)
    acl = sub.add_parser("acl", help="print the router's access control for the inventory")
    add_common(acl)
    acl.set_defaults(run=run_acl)


def run_certs(args: argparse.Namespace) -> int:
    """Write the CA and the missing certificates; print what was written."""
    from fleet.files import FileReadError
    from fleet.security.certs import make_certs  # cryptography loads only for this command

    inventory = inventory_from_args(args)
    out = args.out or inventory.security.certs
    try:
        written = make_certs(inventory, out, days=args.days, force=args.force)
    except FileReadError as exc:
        print(f"fleet certs: {exc}", file=sys.stderr)
        return 2
    print(f"{out}: wrote {', '.join(written) or 'nothing (every certificate exists)'}")
    print("keep ca.key offline; give each host only its own <principal>.pem and .key, and ca.pem")
    return 0


def run_acl(args: argparse.Namespace) -> int:
    """Print the ``access_control`` and ``low_pass_filter`` sections the router will use."""
    from fleet.security.acl import access_control, payload_limits

    inventory = inventory_from_args(args, "router")
    config = {
        "access_control": access_control(inventory),
        "low_pass_filter": payload_limits(inventory),
    }
    print(json.dumps(config, indent=2))
    return 0
