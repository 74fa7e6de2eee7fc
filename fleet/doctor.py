"""``fleet doctor``: what breaks first on a real arm network, each with how to fix it.

Checks, in the order a first bring-up meets them: the network card named in the inventory
(exists, up, has an address), the DDS domain, the DDS peers (resolvable, and reached through
that card, not through another one), the Zenoh router, every process's version and clock
(``info/*/*`` queryables, fleet/wire/info.py), every arm's agent, the arm's feedback (link and
rate as the agent sees them), the access rules (secure fleets), each G1's LocoClient service
name and the coordinator. Host checks are pure functions of this host; fleet checks take an open
``FleetClient``.
"""

from __future__ import annotations

import fcntl
import socket
import struct
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from fleet.client import FleetClient
from fleet.devices import kind_of
from fleet.inventory import Inventory
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from fleet.wire.info import package_version, query_info

Level = Literal["ok", "warn", "fail"]

MIN_FEEDBACK_HZ = 5.0
"""A D1 reports its angles at ~10 Hz; under 5 Hz the link flaps stale (link_stale_s 0.35)."""
CLOCK_WARN_MS = 5.0
CLOCK_FAIL_MS = 50.0
"""Synchronized starts compare each host's wall clock with the ``start_at_ns`` of the host that
sent them: an offset shows as start skew 1:1 (we measure 0.5-1.3 ms of skew on one host). Over
50 ms is visibly unsynchronized; commands also carry a 5 s lifetime checked on the agent's clock."""
DDS_DOMAIN_MAX = 232  # the DDS spec's port mapping ends there
IFF_UP = 0x1
SIOCGIFADDR = 0x8915


@dataclass(frozen=True)
class Check:
    """One finding: ``what`` was checked, ``level``, ``detail`` and, unless ok, ``fix``."""

    what: str
    level: Level
    detail: str
    fix: str = ""

    def lines(self) -> list[str]:
        """``[ OK ] what: detail`` and, unless ok, an indented ``fix:`` line."""
        tag = {"ok": " OK ", "warn": "WARN", "fail": "FAIL"}[self.level]
        out = [f"[{tag}] {self.what}: {self.detail}"]
        if self.fix and self.level != "ok":
            out.append(f"       fix: {self.fix}")
        return out


# ----------------------------------------------------------------------------- this host


def interface_address(name: str) -> str | None:
    """The IPv4 address of interface ``name``, or None."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            raw = fcntl.ioctl(probe.fileno(), SIOCGIFADDR, struct.pack("256s", name.encode()[:15]))
        except OSError:
            return None
    return socket.inet_ntoa(raw[20:24])


def interface_up(name: str) -> bool:
    """True when the kernel has the interface administratively up (IFF_UP)."""
    try:
        return bool(int(Path(f"/sys/class/net/{name}/flags").read_text(), 16) & IFF_UP)
    except (OSError, ValueError):
        return False


def check_interfaces(inventory: Inventory) -> list[Check]:
    """Each card named by an arm: exists, up, has an address."""
    found: list[Check] = []
    names = [n for _i, n in socket.if_nameindex()]
    by_card: dict[str, list[str]] = {}
    for arm in inventory.arms.values():
        by_card.setdefault(arm.interface, []).append(arm.id)
    for card, arms in by_card.items():
        what = f"interface {card or '(DDS chooses)'} ({', '.join(arms)})"
        if not card:
            found.append(Check(what, "ok", '"" in the inventory: CycloneDDS picks a card'))
            continue
        if card not in names:
            found.append(
                Check(
                    what,
                    "fail",
                    f"no such interface on this host (it has {', '.join(names)})",
                    f"set `interface` of {', '.join(arms)} to the card the arm is cabled to "
                    "(`ip -br link`), or run fleet doctor on the host that runs their agent",
                )
            )
            continue
        if not interface_up(card):
            found.append(Check(what, "fail", "down", f"sudo ip link set {card} up"))
            continue
        address = interface_address(card)
        if address is None:
            fix = f"an address on the arm's subnet: sudo ip addr add 192.168.123.10/24 dev {card}"
            found.append(Check(what, "fail", "up, but no IPv4 address", fix))
            continue
        found.append(Check(what, "ok", f"up, {address}"))
    return found


def check_domains(inventory: Inventory) -> list[Check]:
    """Each arm's DDS domain: legal, and 0 for a real arm (D1s ship on domain 0)."""
    found: list[Check] = []
    for arm in inventory.arms.values():
        domain = inventory.domain_of(arm)
        what = f"DDS domain of {arm.id}"
        if not 0 <= domain <= DDS_DOMAIN_MAX:
            found.append(Check(what, "fail", f"{domain} is not a DDS domain id", "use 0..232"))
        elif not arm.simulated and domain != 0:
            fix = "set [dds] domain_id = 0 (or the arm's domain_id) unless you changed the arm's"
            found.append(Check(what, "warn", f"{domain}; a D1 ships on domain 0", fix))
        else:
            found.append(Check(what, "ok", str(domain)))
    return found


def route_source(peer: str) -> str | None:
    """The local address this host would use to reach ``peer`` (no packet is sent)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect((peer, 7400))
        except OSError:
            return None
        return str(probe.getsockname()[0])


def check_peers(inventory: Inventory) -> list[Check]:
    """Each arm's DDS unicast peers: resolvable, routed through the arm's own card."""
    found: list[Check] = []
    seen: set[tuple[str, str]] = set()
    for arm in inventory.arms.values():
        for peer in inventory.peers_of(arm):
            if (peer, arm.interface) in seen:
                continue
            seen.add((peer, arm.interface))
            what = f"DDS peer {peer} ({arm.interface or 'any card'})"
            try:
                address = socket.gethostbyname(peer)
            except OSError:
                fix = "use the arm's IP address (a D1 is 192.168.123.x by default) in `peers`"
                found.append(Check(what, "fail", "does not resolve", fix))
                continue
            source = route_source(address)
            own = interface_address(arm.interface) if arm.interface else None
            if source is None:
                fix = f"add a route or an address on {arm.interface or 'the arm card'}"
                found.append(Check(what, "fail", f"no route to {address}", fix))
            elif own is not None and source != own and not address.startswith("127."):
                found.append(
                    Check(
                        what,
                        "fail",
                        f"this host reaches {address} from {source}, not from "
                        f"{arm.interface} ({own}): DDS traffic would leave through another card",
                        f"put {arm.interface} on the peer's subnet (e.g. 192.168.123.0/24) "
                        "and no other card on it",
                    )
                )
            else:
                found.append(Check(what, "ok", f"{address}, routed from {source}"))
    return found


def check_access_rules(inventory: Inventory) -> list[Check]:
    """With security on: the generated access control allows every key each unit's agent
    publishes and serves, each commander queries and each reader reads (a denied key is
    dropped by the router without a word to either side)."""
    if not inventory.security.enabled:
        return []
    from fleet.security.coverage import gaps

    missing = gaps(inventory)
    what = "access rules"
    if not missing:
        return [Check(what, "ok", "every key of every unit is allowed to who uses it")]
    shown = "; ".join(str(gap) for gap in missing[:5])
    more = f" (and {len(missing) - 5} more)" if len(missing) > 5 else ""
    fix = (
        "check the roles in [principals] (an agent's principal needs role 'agent'); if they "
        "are right, the generated rules miss a channel: report it with this line"
    )
    return [Check(what, "fail", f"{len(missing)} keys denied: {shown}{more}", fix)]


def host_checks(inventory: Inventory) -> list[Check]:
    """Every check of this host's configuration: the network, and the access rules."""
    return [
        *check_interfaces(inventory),
        *check_domains(inventory),
        *check_peers(inventory),
        *check_access_rules(inventory),
    ]


# ----------------------------------------------------------------------------- the fleet


def check_processes(client: FleetClient) -> list[Check]:
    """Every process's version (all equal to ours) and its host's clock offset."""
    replies, bad = query_info(client.session, client.inventory.fleet)
    ours = package_version()
    found: list[Check] = []
    if bad:
        found.append(Check("process info", "warn", f"{bad} undecodable replies on info/*/*"))
    if not replies:
        return [
            *found,
            Check(
                "processes",
                "warn",
                "no process answered on info/*/* (processes older than fleet doctor?)",
                "upgrade and restart the fleet's processes",
            ),
        ]
    by_host: dict[str, tuple[float, float]] = {}
    for reply in replies:
        info = reply.info
        what = f"{info.role} {info.principal} on {info.host} pid {info.pid}"
        if info.version != ours:
            fix = f"install d1-fleet {ours} on {info.host} and restart it (or upgrade this CLI)"
            found.append(Check(what, "fail", f"version {info.version}, this CLI {ours}", fix))
        else:
            found.append(Check(what, "ok", f"version {info.version}"))
        if info.role == "agent":
            found.append(_datagram_check(client, what, info.datagram))
        best = by_host.get(info.host)
        if best is None or reply.uncertainty_ms < best[1]:
            by_host[info.host] = (reply.offset_ms, reply.uncertainty_ms)
    for host, (offset, uncertainty) in sorted(by_host.items()):
        found.append(_clock_check(host, offset, uncertainty))
    return found


def _datagram_check(client: FleetClient, what: str, path: str | None) -> Check:
    """An agent's second path for stops (UDP, or QUIC datagrams in a secure fleet)."""
    what = f"{what}: stops' datagram path"
    if not client.inventory.datagram.enabled:
        return Check(what, "ok", "off in the inventory ([zenoh] datagram = false)")
    if path is None:
        return Check(
            what,
            "warn",
            "not open: its stops, acks and heartbeats take the reliable path only (slower "
            "under packet loss)",
            "check that the router listens on the datagram twin of its endpoints (fleet "
            "routers do) and that no firewall drops UDP to its port",
        )
    return Check(what, "ok", path)


def _clock_check(host: str, offset_ms: float, uncertainty_ms: float) -> Check:
    what = f"clock of {host}"
    detail = f"offset {offset_ms:+.1f} ms (+/- {uncertainty_ms:.1f} ms) from this host"
    beyond = abs(offset_ms) - uncertainty_ms
    fix = "synchronize the hosts' clocks (chrony/NTP, or PTP on the arm network)"
    if beyond > CLOCK_FAIL_MS:
        return Check(what, "fail", detail + ": synchronized starts will skew", fix)
    if beyond > CLOCK_WARN_MS:
        return Check(what, "warn", detail, fix)
    return Check(what, "ok", detail)


def check_arms(client: FleetClient, arms: Iterable[str]) -> list[Check]:
    """Each arm: its agent's token, its link and its feedback rate (from its diag)."""
    arms = list(arms)
    alive = client.agents_alive()
    snapshot = client.snapshot(arms, wait_s=1.5)
    rates = _diag_rates(client, arms, wait_s=1.6)
    found: list[Check] = []
    for arm in arms:
        config = client.inventory.arm(arm)
        if arm not in alive:
            found.append(
                Check(
                    f"agent of {arm}",
                    "fail",
                    f"no liveliness token on {client.keys.arm(arm, keys.AGENT)}",
                    f"start it: edge-agent --arm {arm} --inventory {client.inventory.path} "
                    "(or `fleet deploy systemd` and systemctl start it)",
                )
            )
            continue
        found.append(Check(f"agent of {arm}", "ok", "alive"))
        status, _joints = snapshot.get(arm, (None, None))
        rate = rates.get(arm)
        what = f"feedback of {arm}"
        silent_fix = (
            f"the agent hears nothing on rt/arm_Feedback{config.suffix}: is the arm powered, "
            f"cabled to {config.interface or 'a card'}, on domain "
            f"{client.inventory.domain_of(config)}, with suffix {config.suffix!r} and peers "
            f"{', '.join(client.inventory.peers_of(config)) or 'none'}?"
        )
        if status is None or status.link != "ok":
            link = "no status" if status is None else f"link {status.link}"
            found.append(Check(what, "fail", link, silent_fix))
        elif rate is None:
            found.append(Check(what, "warn", "link ok, no diag within 1.6 s"))
        elif rate < MIN_FEEDBACK_HZ:
            fix = "a loaded host, a congested card or a lossy cable: `fleet hz arm/*/joints`"
            found.append(Check(what, "fail", f"{rate:.1f} Hz (a D1 sends ~10 Hz)", fix))
        else:
            found.append(Check(what, "ok", f"link ok, {rate:.1f} Hz"))
        if status is not None and status.estopped:
            fix = f"find out why ({status.stop_reason}), then: fleet reset {arm}"
            found.append(Check(f"stop of {arm}", "warn", "latched", fix))
    return found


def check_devices(client: FleetClient, devices: Iterable[str]) -> list[Check]:
    """Each device: its agent's token and its DDS link and rate (from its diag)."""
    found: list[Check] = []
    inventory = client.inventory
    for device in devices:
        config = inventory.device(device)
        kind = kind_of(config).key
        token = client.keys.device(kind, device, keys.AGENT)
        alive = any(r.ok is not None for r in client.session.liveliness().get(token, timeout=1.0))
        if not alive:
            fix = (
                f"start it: edge-agent --interface {config.interface or '<card>'} --inventory "
                f"{inventory.path} (or `fleet deploy systemd` and systemctl start it)"
            )
            found.append(
                Check(f"agent of {device}", "fail", f"no liveliness token on {token}", fix)
            )
            continue
        found.append(Check(f"agent of {device}", "ok", "alive"))
        diag = _latest_diag(client, client.keys.device(kind, device, keys.DIAG), wait_s=1.6)
        what = f"state of {kind} {device}"
        if diag is None:
            found.append(Check(what, "warn", "alive, no diag within 1.6 s"))
        elif diag.link != "ok":
            fix = (
                f"the agent hears no state from {device}: is it powered, on "
                f"{config.interface or 'a card'} and on this DDS domain? ({diag.last_error})"
            )
            found.append(Check(what, "fail", f"link {diag.link}", fix))
        else:
            found.append(Check(what, "ok", f"link ok, {diag.feedback_rate_hz:.1f} Hz"))
    return found


def _latest_diag(client: FleetClient, key: str, wait_s: float) -> m.Diag | None:
    got: list[m.Diag] = []
    arrived = threading.Event()

    def on_diag(sample: object) -> None:
        try:
            got.append(payloads.DIAG.decode(sample.payload.to_bytes()))  # type: ignore[attr-defined]
        except payloads.PayloadError:
            return
        arrived.set()

    subscriber = client.session.declare_subscriber(key, on_diag)
    arrived.wait(wait_s)
    subscriber.undeclare()
    return got[-1] if got else None


def _diag_rates(client: FleetClient, arms: list[str], wait_s: float) -> dict[str, float]:
    rates: dict[str, float] = {}

    def on_diag(sample: object) -> None:
        try:
            key = client.keys.parse_arm_key(str(sample.key_expr))  # type: ignore[attr-defined]
            diag = payloads.DIAG.decode(sample.payload.to_bytes())  # type: ignore[attr-defined]
        except (keys.KeyError_, payloads.PayloadError):
            return
        rates[key.arm] = diag.feedback_rate_hz  # one writer (the Zenoh thread), read after

    subscriber = client.session.declare_subscriber(client.keys.all_arms(keys.DIAG), on_diag)
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not all(a in rates for a in arms):
        time.sleep(0.05)
    subscriber.undeclare()
    return dict(rates)


def check_g1_services(states: dict[str, object]) -> list[Check]:
    """Each G1 (``g1/<id>`` of ``FleetClient.device_snapshot``): which LocoClient service name
    its agent uses and whether it answered GetFsmId (``sport``: ai_sport >= 8.2, ``loco``:
    before; a wrong name times out every call, the stop's included)."""
    found: list[Check] = []
    for label, state in states.items():
        if not label.startswith("g1/"):
            continue
        what = f"LocoClient service of {label}"
        if state is None:
            fix = f"start its agent: edge-agent --device {label.partition('/')[2]}"
            found.append(
                Check(what, "warn", "no G1 state (no agent, or no rt/sportmodestate)", fix)
            )
            continue
        service = getattr(state, "service", None)
        setting = getattr(state, "service_setting", "sport")
        if service is None:
            fix = "is the G1's high-level service running, on this DDS domain and card?"
            found.append(Check(what, "fail", "auto: neither sport nor loco answered GetFsmId", fix))
        elif not getattr(state, "service_answered", False):
            other = "loco" if service == "sport" else "sport"
            fix = (
                f'set service = "{other}" (or "auto") under [g1.{label.partition("/")[2]}]: '
                "ai_sport < 8.2 serves loco, >= 8.2 sport"
            )
            found.append(Check(what, "fail", f"{service}: no answer to GetFsmId", fix))
        else:
            how = " (auto)" if setting == "auto" else ""
            found.append(Check(what, "ok", f"{service}{how}: answered GetFsmId"))
    return found


def check_coordinator(client: FleetClient) -> Check:
    """The coordinator's fleet state (synchronized moves and the fleet heartbeat need it)."""
    state = client.fleet_state(wait_s=1.0)
    if state is None:
        fix = f"start it: fleet coordinator --inventory {client.inventory.path}"
        return Check("coordinator", "warn", "no fleet state within 1 s", fix)
    return Check("coordinator", "ok", f"{state.coordinator}, {len(state.arms)} arms")
