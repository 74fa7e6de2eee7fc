"""``fleet demo --secure``: the demo with mutual TLS and the access control of the inventory.

The demo's inventory is copied into a temporary directory with a ``[security]`` section added
(mode ``mtls``, certificates in that directory, made by ``fleet certs``), and every process
connects on ``tls/`` endpoints. The directory, keys included, is removed when the demo ends.
The demo prints the copy's path: the CLI needs it (``--inventory``) to connect with a
certificate. The arms' calibration files, relative to the inventory's folder, are reached
through links in the directory to the original folder's (``fleet calibrate`` writes there too).
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
    _link_calibrations(inventory, workdir)
    path = workdir / "inventory.toml"
    path.write_text(secure_text, encoding="utf-8")
    args.inventory = str(path)
    args.endpoint = [e.replace("tcp/", "tls/", 1) for e in inventory.endpoints]
    secure = load_inventory(path).with_domain(inventory.domain_id).with_endpoints(args.endpoint)
    make_certs(secure, secure.security.certs, days=2)
    return secure.with_principal(inventory.principal)


def _link_calibrations(inventory: Inventory, workdir: Path) -> None:
    """Link each folder (or file) holding an arm's calibration, relative to the inventory's
    folder, from ``workdir`` to the original (made if missing, as ``fleet calibrate`` would)."""
    origin = Path(inventory.path).parent.resolve()
    for arm in inventory.arms:
        relative = Path(inventory.arm(arm).calibration or f"calibration/{arm}.json")
        if relative.is_absolute():
            continue
        top = relative.parts[0]
        link, target = workdir / top, origin / top
        if len(relative.parts) > 1:
            target.mkdir(parents=True, exist_ok=True)
        if not link.exists() and not link.is_symlink():
            link.symlink_to(target)
