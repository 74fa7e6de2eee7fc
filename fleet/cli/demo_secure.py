"""``fleet demo --secure``: the demo with mutual TLS and the access control of the inventory.

The demo's inventory is copied into a temporary directory with a ``[security]`` section added
(mode ``mtls``, certificates in that directory, made by ``fleet certs``), and every process
connects on ``tls/`` endpoints. The directory, keys included, is removed when the demo ends.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fleet.inventory import Inventory, InventoryError, load_inventory


def secure_demo_inventory(
    args: argparse.Namespace, inventory: Inventory, workdir: Path
) -> Inventory:
    """Write the secure copy of the demo's inventory in ``workdir``, make its certificates,
    point ``args`` at it (the children load it), and return it as loaded."""
    from fleet.security.certs import make_certs

    text = Path(args.inventory).read_text(encoding="utf-8")
    if inventory.security.enabled:
        secure_text = text  # the inventory already says how: keep it
    elif "[security]" in text:
        raise InventoryError(f"{args.inventory}: --secure needs [security] mode mtls or none")
    else:
        certs = workdir / "certs"
        secure_text = f'{text}\n[security]\nmode = "mtls"\ncerts = "{certs}"\n'
    path = workdir / "inventory.toml"
    path.write_text(secure_text, encoding="utf-8")
    args.inventory = str(path)
    args.endpoint = [e.replace("tcp/", "tls/", 1) for e in inventory.endpoints]
    secure = load_inventory(path).with_domain(inventory.domain_id).with_endpoints(args.endpoint)
    make_certs(secure, secure.security.certs, days=2)
    return secure.with_principal(inventory.principal)
