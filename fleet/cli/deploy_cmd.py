"""``fleet deploy systemd [--out DIR]``: systemd units for the fleet's long-running processes.

One unit each for the router, the coordinator and the viewer, and one agent per network card
(``edge-agent --interface CARD``: one DDS participant per card, NIC binding). Every unit
restarts on failure, logs to the journal, and starts after the router (agents and the
coordinator retry the router anyway; the order keeps the journal quiet). Stopping the router
does not stop the others: an agent without a router keeps holding its arms (watchdog).
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

from fleet.inventory import Inventory
from fleet.runtime import inventory_from_args

PREFIX = "d1-fleet"


def register(
    sub: argparse._SubParsersAction, add_common: Callable[[argparse.ArgumentParser], None]
) -> None:  # type: ignore[type-arg]
    """Add ``deploy systemd``."""
    deploy = sub.add_parser("deploy", help="write service files for the fleet's processes")
    kinds = deploy.add_subparsers(dest="deploy_kind", required=True, metavar="systemd")
    systemd = kinds.add_parser(
        "systemd", help="systemd units (router, coordinator, agents, viewer)"
    )
    add_common(systemd)
    systemd.add_argument("--out", default="systemd", help="directory for the units (./systemd)")
    systemd.add_argument("--user", default=None, help="User= of every unit (default: none)")
    systemd.add_argument(
        "--bin-dir",
        default=str(Path(sys.executable).parent),
        help="where `fleet` and `edge-agent` are installed (default: this Python's bin)",
    )
    systemd.set_defaults(run=run_systemd)


_C_ESCAPES = {"\\": "\\\\", '"': '\\"', "\n": "\\n", "\t": "\\t", "\r": "\\r"}


def specifiers(value: str) -> str:
    """``value`` with systemd's specifier and variable expansion turned off (``%`` -> ``%%``,
    ``$`` -> ``$$``; systemd.syntax(7), systemd.service(5) "Command lines")."""
    return value.replace("%", "%%").replace("$", "$$")


def exec_word(value: str) -> str:
    """One argument of ``ExecStart=``, double-quoted and escaped: spaces stay one argument,
    ``%h`` and ``$HOME`` stay literal, a quote or backslash cannot end it, a control character
    is a C escape (never a new line of the unit)."""
    out = []
    for char in specifiers(value):
        if char in _C_ESCAPES:
            out.append(_C_ESCAPES[char])
        elif ord(char) < 0x20 or ord(char) == 0x7F:
            out.append(f"\\x{ord(char):02x}")
        else:
            out.append(char)
    return '"' + "".join(out) + '"'


def plain_value(value: str) -> str:
    """A one-line setting (``Description=``): specifiers escaped, control characters spaces."""
    return "".join(" " if ord(c) < 0x20 or ord(c) == 0x7F else c for c in specifiers(value))


def _unit(description: str, exec_start: list[str], user: str | None, after_router: bool) -> str:
    order = f"After=network-online.target {PREFIX}-router.service\nWants=network-online.target\n"
    lines = [
        "[Unit]",
        f"Description={plain_value(f'd1-fleet {description}')}",
        order.rstrip()
        if after_router
        else "After=network-online.target\nWants=network-online.target",
        "StartLimitIntervalSec=120",
        "StartLimitBurst=10",
        "",
        "[Service]",
        "Type=simple",
        f"ExecStart={' '.join(exec_word(arg) for arg in exec_start)}",
        "Restart=on-failure",
        "RestartSec=2",
        "KillSignal=SIGTERM",
        "TimeoutStopSec=15",
        "StandardOutput=journal",
        "StandardError=journal",
        f"SyslogIdentifier={PREFIX}",
        "Environment=PYTHONUNBUFFERED=1",
    ]
    if user:
        lines.append(f"User={plain_value(user)}")
    lines += ["", "[Install]", "WantedBy=multi-user.target", ""]
    return "\n".join(lines)


def units(inventory: Inventory, bin_dir: Path, user: str | None = None) -> dict[str, str]:
    """File name -> unit text."""
    inv = ["--inventory", str(Path(inventory.path).resolve())]
    fleet, agent = str(bin_dir / "fleet"), str(bin_dir / "edge-agent")
    out = {
        f"{PREFIX}-router.service": _unit("Zenoh router", [fleet, "router", *inv], user, False),
        f"{PREFIX}-coordinator.service": _unit(
            "coordinator", [fleet, "coordinator", *inv], user, True
        ),
        f"{PREFIX}-viewer.service": _unit("viewer", [fleet, "viewer", *inv], user, True),
    }
    # One agent per network card (and agent identity: one process has one certificate),
    # serving every arm and device on that card.
    groups: dict[tuple[str, str], list[str]] = {}
    for unit in [*inventory.arms.values(), *inventory.devices.values()]:
        identity = unit.agent if inventory.security.enabled else ""
        groups.setdefault((unit.interface, identity), []).append(unit.id)
    shared_cards = {card for card, _p in groups if sum(c == card for c, _ in groups) > 1}
    for (card, principal), served in sorted(groups.items()):
        name = re.sub(r"[^A-Za-z0-9_.-]", "_", card) or "any"
        argv = [agent, "--interface", card, *inv]  # "" (quoted): any card
        if card in shared_cards:  # several identities on this card: one process each
            name += f"-{principal}"
            argv += ["--principal", principal]
            for unit in served:
                argv += ["--arm" if unit in inventory.arms else "--device", unit]
        text = _unit(f"edge agent of {', '.join(served)} ({card or 'any card'})", argv, user, True)
        out[f"{PREFIX}-agent-{name}.service"] = text
    return out


def run_systemd(args: argparse.Namespace) -> int:
    """Write the units and say how to install them."""
    inventory = inventory_from_args(args)
    bin_dir = Path(args.bin_dir)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = units(inventory, bin_dir, args.user)
    for name, text in written.items():
        (out / name).write_text(text, encoding="utf-8")
        print(out / name)
    print(
        f"install: sudo cp {out}/{PREFIX}-*.service /etc/systemd/system/ && sudo systemctl "
        f"daemon-reload && sudo systemctl enable --now {' '.join(written)}\n"
        f"logs: journalctl -u '{PREFIX}-*' -f"
    )
    return 0
