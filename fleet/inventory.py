"""inventory.toml -> a frozen, validated Inventory.

Every error names the file and the path inside it (``inventory.toml: arms.a1: ...``); unknown or
misspelled fields are errors, not silently ignored. ``[defaults]`` applies to every arm; a field
set in ``[arms.<id>]`` overrides it. docs/reference/inventory.md documents each field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal, NamedTuple, get_args

import msgspec
from msgspec import Struct

from fleet.contact.config import ContactConfig, check_config
from fleet.contact.dynamics import SimDynamics
from fleet.d1 import topics
from fleet.d1.limits import (
    GRIPPER_CLOSED_DEG,
    GRIPPER_OPEN_DEG,
    JOINT_COUNT,
    JointRanges,
    joint_ranges,
)
from fleet.devices import DeviceKind, kinds
from fleet.devices.base import NETWORK_FIELDS, DeviceBase
from fleet.ros2.config import Ros2Section, check_section
from fleet.security_config import (
    DEFAULT_PRINCIPALS,
    ROLES,
    Role,
    Security,
    SecuritySection,
    resolve,
)
from fleet.tomlfile import TomlError, brief, decode_toml, read_text
from fleet.wire.keys import KeyError_, check_name
from fleet.wire.session import Datagram

DEFAULT_INVENTORY = "inventory.toml"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

StopAction = Literal["hold", "unload", "power_off"]
SimAckSeq = Literal["echo", "fixed"]
SimExecAck = Literal["at_once", "on_arrival"]
SimEnable = Literal["table", "strength"]
EXEC_ACK_TIMEOUT_OPS = ("move_joint", "move_joints", "torque", "power", "zero")
"""The ops of the per-op execute-ack timeout table (the D1 commands they send)."""


class DdsNetwork(NamedTuple):
    """What one DDS participant is configured from (``ChannelFactory::Init``'s arguments)."""

    domain_id: int
    interface: str
    """``""``: CycloneDDS chooses the interface."""
    peers: tuple[str, ...]
    multicast: bool


class InventoryError(ValueError):
    """The inventory file is missing, unreadable or invalid; the message names file and path."""


class FleetSection(Struct, frozen=True, forbid_unknown_fields=True):
    """``[fleet]``."""

    name: str


class ZenohSection(Struct, frozen=True, forbid_unknown_fields=True):
    """``[zenoh]``: the router listens on ``endpoints``; every other process connects to them."""

    endpoints: list[str] = msgspec.field(default_factory=lambda: [DEFAULT_ENDPOINT])
    datagram: bool = True
    """Stops, their acks and heartbeats also go best-effort over a UDP link beside each
    ``tcp/`` endpoint (issue 24; README "Reliability"). Never on ``tls/`` endpoints."""
    stop_dscp: Annotated[int, msgspec.Meta(ge=0, le=63)] | None = None
    """DSCP code point marked on the datagram link's packets (46: EF), for a lab's switches."""


class DdsSection(Struct, frozen=True, forbid_unknown_fields=True):
    """``[dds]``: fleet-wide DDS defaults."""

    domain_id: int = 0
    peers: list[str] = msgspec.field(default_factory=lambda: ["127.0.0.1"])


class ArmConfig(Struct, frozen=True, forbid_unknown_fields=True):
    """One arm: ``[defaults]`` merged with ``[arms.<id>]``."""

    id: str = ""
    agent: str = ""
    """The principal of the edge agent serving this arm (default ``agent-<id>``): with TLS, the
    common name of its certificate; the router lets only it publish this arm's state."""
    suffix: str = ""
    interface: str = "lo"
    """The network card of the arm; ``""`` lets CycloneDDS choose one."""
    peers: list[str] | None = None
    multicast: bool = False
    """Multicast discovery as Unitree's SDK does it, for real arm networks only: tests and the
    demo stay unicast on loopback (a test host's multicast reaches every other test's arms)."""
    domain_id: int | None = None
    simulated: bool = False
    base_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    stop_action: StopAction = "hold"
    link_stale_s: float = 0.35
    link_lost_s: float = 2.0
    enable_mode: int = 1
    """Funcode 5 ``mode`` sent to enable all joints: 1 (the spec's table: 1 = enable) or a
    holding strength up to 80000 (the spec's note: 0..80000, 80000 fully locked). After every
    enable the agent checks that the arm holds its pose and warns naming this setting."""
    recv_ack_timeout_s: float = 0.5
    exec_ack_timeout_s: float = 2.0
    exec_ack_timeouts: dict[str, float] = msgspec.field(default_factory=dict)
    """Execute-ack timeout per op (``move_joint``, ``move_joints``, ``torque``, ``power``,
    ``zero``) over the built-in table (``fleet/d1arm/acks.py``: moves 5 s, zero 10 s, the rest
    ``exec_ack_timeout_s``): "executed" may mean "motion finished"."""
    joint_sign: tuple[int, ...] = (1,) * JOINT_COUNT
    watchdog_s: float = 0.5
    lease_s: float = 3.0
    max_speed_deg_s: float = 360.0
    """Faster than any D1 joint moves (plausible arms: up to 180 deg/s): an angle report that
    implies more is a sensor fault or a forgery, never a pose to hold."""
    contact: ContactConfig = ContactConfig()
    gripper_closed_deg: float = GRIPPER_CLOSED_DEG
    gripper_open_deg: float = GRIPPER_OPEN_DEG
    """What ``angle6`` reads with the gripper closed and fully open: its range and its direction
    (the spec gives only a 0-65 mm stroke; the default reads servo degrees, 0 closed)."""
    sim_ack_seq: SimAckSeq = "echo"
    """How the simulated arm reads the spec's ack seq: ``echo`` the command's seq (the table's
    "caller generates"), or ``fixed``: always 10 (every ack example)."""
    sim_error_status: int = 0
    """The ``error_status`` the simulated arm reports while abnormal: 0 (the table) or a
    bitfield value (the contact plan's reading)."""
    sim_exec_ack: SimExecAck = "at_once"
    """When the simulated arm sends a motion's execute ack: ``at_once`` (when it took the
    target) or ``on_arrival`` (when the joints reached it: "executed" as "motion finished")."""
    sim_enable: SimEnable = "table"
    """How the simulated arm reads funcode 5 ``mode``: ``table`` (any mode > 0 enables) or
    ``strength`` (0..80000: below ``SAG_BELOW`` the arm is limp and its shoulder sags)."""
    sim_feedback_writers: int = 1
    """How many DDS writers the simulated arm's feedback comes from: 1, or 3 as the arm's own
    driver does it (seed 000: marm_communication sends the angles, marm_control the acks,
    marm_controller the status and motor reports; three participants)."""

    @property
    def joint_ranges_deg(self) -> JointRanges:
        """(min, max) per wire joint of this arm: the spec's, and its gripper's own."""
        return joint_ranges(self.gripper_closed_deg, self.gripper_open_deg)

    @property
    def gripper_closing_sign(self) -> float:
        """-1.0 when closing lowers ``angle6`` (the default), +1.0 when it raises it."""
        return -1.0 if self.gripper_open_deg > self.gripper_closed_deg else 1.0

    calibration: str = ""
    """The arm's calibration file (``fleet calibrate`` writes it; the agent's contact detector
    reads it): relative to the inventory's folder; default ``calibration/<id>.json``."""
    sim_dynamics: SimDynamics = SimDynamics()
    """How ``fleet sim`` makes this arm respond (dead time, lag, speed limit, servo per mode;
    feedback rate and jitter): an arm unlike the detector's assumptions, for tests."""


class CoordinatorSection(Struct, frozen=True, forbid_unknown_fields=True):
    """``[coordinator]``: heartbeat rate and the lead-in of synchronized starts."""

    heartbeat_hz: float = 10.0
    sync_lead_s: float = 0.3
    offline_after_s: float = 1.0


class Inventory(Struct, frozen=True):
    """The validated fleet description."""

    path: str
    fleet: str
    endpoints: list[str]
    domain_id: int
    peers: list[str]
    arms: dict[str, ArmConfig]
    groups: dict[str, list[str]]
    coordinator: CoordinatorSection = CoordinatorSection()
    security: Security = Security()
    principals: dict[str, Role] = {}
    principal: str = "operator"
    """Who this process acts as (``--principal``; each process has its default)."""
    datagram: Datagram = Datagram()
    """The datagram path of stops (``[zenoh] datagram``, ``stop_dscp``)."""
    devices: dict[str, DeviceBase] = {}
    """Devices beside the arms (``fleet/devices``: grippers, G1s), by id; ids are unique
    across arms and devices."""
    ros2_section: Ros2Section | None = None
    """``[ros2]`` as written (None: no such section; the router's access control then has no
    ROS keys)."""

    @property
    def ros2(self) -> Ros2Section:
        """``[ros2]``, or its defaults: the fleet on rmw_zenoh's wire (docs/guide/ros2.md)."""
        return self.ros2_section if self.ros2_section is not None else Ros2Section()

    def device(self, device_id: str) -> DeviceBase:
        """The device ``device_id``; raises InventoryError naming the known devices."""
        try:
            return self.devices[device_id]
        except KeyError:
            known = ", ".join(self.devices) or "none"
            raise InventoryError(
                f"{self.path}: no device {device_id!r} (known devices: {known})"
            ) from None

    def device_network(self, device_ids: list[str]) -> DdsNetwork:
        """The one DDS network ``device_ids`` share (one agent process per network)."""
        return self.network_of([], device_ids)

    def units_on(self, interface: str) -> tuple[list[str], list[str]]:
        """The arms and the devices on network interface ``interface``."""
        arms = [a.id for a in self.arms.values() if a.interface == interface]
        return arms, [d.id for d in self.devices.values() if d.interface == interface]

    def agent_of(self, unit: str) -> str:
        """The principal of the agent serving arm or device ``unit``."""
        return self.arms[unit].agent if unit in self.arms else self.device(unit).agent

    def role_of(self, principal: str) -> Role | None:
        """The role of ``principal``; None for a principal the inventory does not know."""
        return self.principals.get(principal)

    def with_principal(self, principal: str) -> Inventory:
        """A copy for a process acting as ``principal``."""
        check_name("principal", principal)
        return msgspec.structs.replace(self, principal=principal)

    def calibration_path(self, arm_id: str) -> Path:
        """The calibration file of ``arm_id`` (its ``calibration``, relative to the inventory's
        folder; default ``calibration/<id>.json``)."""
        name = self.arm(arm_id).calibration or f"calibration/{arm_id}.json"
        return Path(self.path).parent / name

    def arm(self, arm_id: str) -> ArmConfig:
        """The arm ``arm_id``; raises InventoryError naming the known arms."""
        try:
            return self.arms[arm_id]
        except KeyError:
            known = ", ".join(self.arms) or "none"
            raise InventoryError(f"{self.path}: no arm {arm_id!r} (known arms: {known})") from None

    def resolve(self, target: str) -> list[str]:
        """Arm ids for ``target``: an arm id, a group name, or ``all``."""
        if target == "all":
            return list(self.arms)
        if target in self.groups:
            return list(self.groups[target])
        return [self.arm(target).id]

    def domain_of(self, arm: ArmConfig) -> int:
        """The arm's DDS domain (its own, or the fleet's)."""
        return self.domain_id if arm.domain_id is None else arm.domain_id

    def peers_of(self, arm: ArmConfig) -> tuple[str, ...]:
        """The arm's DDS unicast peers (its own, or the fleet's)."""
        return tuple(self.peers if arm.peers is None else arm.peers)

    def network_of(self, arm_ids: list[str], device_ids: list[str] | None = None) -> DdsNetwork:
        """The one (domain, interface, peers, multicast) that ``arm_ids`` and ``device_ids``
        share. One process serves one network: CycloneDDS takes one configuration per domain
        and process, and robots on different cards with the same topics must not hear each
        other (NIC binding)."""
        units: list[ArmConfig | DeviceBase] = [self.arm(a) for a in arm_ids]
        units += [self.device(d) for d in device_ids or ()]
        networks = {
            DdsNetwork(
                self.domain_id if u.domain_id is None else u.domain_id,
                u.interface,
                tuple(self.peers if u.peers is None else u.peers),
                u.multicast,
            )
            for u in units
        }
        if len(networks) != 1:
            raise InventoryError(
                f"{self.path}: robots on different DDS domains or interfaces need one process "
                f"per network interface ({', '.join(f'{u.id}: {u.interface}' for u in units)})"
            )
        return networks.pop()

    def with_domain(self, domain_id: int) -> Inventory:
        """A copy with every arm on ``domain_id`` (tests and the demo isolate runs this way)."""
        arms = {k: msgspec.structs.replace(a, domain_id=None) for k, a in self.arms.items()}
        devices = {k: msgspec.structs.replace(d, domain_id=None) for k, d in self.devices.items()}
        return msgspec.structs.replace(self, domain_id=domain_id, arms=arms, devices=devices)

    def with_endpoints(self, endpoints: list[str]) -> Inventory:
        """A copy whose processes meet on ``endpoints``."""
        return msgspec.structs.replace(self, endpoints=list(endpoints))


def _enum_choices() -> dict[str, tuple[str, ...]]:
    """Fields whose value is one of a few words, and those words (an error lists them)."""
    from fleet.security_config import Role, SecurityMode

    return {
        "stop_action": get_args(StopAction),
        "sim_ack_seq": get_args(SimAckSeq),
        "sim_exec_ack": get_args(SimExecAck),
        "sim_enable": get_args(SimEnable),
        "mode": get_args(SecurityMode),
        "role": get_args(Role),
    }


def _fail(path: str, where: str, exc: msgspec.ValidationError | str) -> InventoryError:
    text = str(exc)
    if text.startswith("Invalid enum value"):
        field = text.rpartition(".")[2].rstrip("`").split("[")[0]
        choices = _enum_choices().get(field)
        if choices:
            text += f" (one of: {', '.join(choices)})"
    if where:
        text = text.replace("`$", f"`$.{where}")
    return InventoryError(f"{path}: {where + ': ' if where else ''}{text}")


def _convert(raw: Any, kind: type[Any], path: str, where: str) -> Any:
    try:
        return msgspec.convert(raw, kind)
    except msgspec.ValidationError as exc:
        raise _fail(path, where, exc) from None


def _check_finite(section: Struct, path: str, where: str) -> None:
    """TOML allows nan and inf, and every comparison with nan is False: refuse them."""
    for name in section.__struct_fields__:
        value = getattr(section, name)
        if isinstance(value, Struct):
            _check_finite(value, path, f"{where}.{name}")
            continue
        values = value if isinstance(value, (tuple, list)) else (value,)
        if any(isinstance(v, float) and not math.isfinite(v) for v in values):
            raise _fail(path, where, f"{name} = {value!r} is not a finite number")


def _network_name_problem(what: str, value: str) -> str | None:
    """Why ``value`` cannot be an interface name or a peer address, or None. They go into the
    CycloneDDS XML: a control character there (TOML's ``\\f``, ``\\u0001``) made the agent
    fail at its first DDS participant with "Non specific error", far from the file (fuzzing)."""
    if not value or len(value) > 255 or not value.isprintable():
        return f"{what} {brief(value)} must be 1..255 printable characters"
    return None


def _check_network(unit: ArmConfig | DeviceBase, path: str, where: str) -> None:
    """An arm's or a device's interface and peers (the same rules: one DDS network)."""
    problems = [_network_name_problem("interface", unit.interface) if unit.interface else None]
    problems += [_network_name_problem("peer", peer) for peer in unit.peers or ()]
    for problem in problems:
        if problem is not None:
            raise _fail(path, where, problem)


def _check_arm(arm: ArmConfig, path: str) -> None:
    where = f"arms.{arm.id}"
    _check_finite(arm, path, where)
    _check_network(arm, path, where)
    suffix_problem = topics.suffix_problem(arm.suffix)
    if suffix_problem is not None:
        raise _fail(path, where, suffix_problem)
    try:
        check_name("agent", arm.agent)
    except KeyError_ as exc:
        raise _fail(path, where, str(exc)) from None
    if len(arm.joint_sign) != JOINT_COUNT or any(s not in (1, -1) for s in arm.joint_sign):
        raise _fail(path, where, f"joint_sign must be {JOINT_COUNT} values of 1 or -1")
    if arm.domain_id is not None and not 0 <= arm.domain_id <= 232:
        raise _fail(path, where, f"domain_id {brief(arm.domain_id)} is outside 0..232")
    if not 0 < arm.link_stale_s < arm.link_lost_s:
        raise _fail(path, where, "need 0 < link_stale_s < link_lost_s")
    if arm.recv_ack_timeout_s <= 0 or arm.exec_ack_timeout_s <= 0:
        raise _fail(path, where, "ack timeouts must be positive")
    for op, timeout_s in arm.exec_ack_timeouts.items():
        if op not in EXEC_ACK_TIMEOUT_OPS:
            raise _fail(
                path,
                f"{where}.exec_ack_timeouts",
                f"unknown op {op!r} (one of: {', '.join(EXEC_ACK_TIMEOUT_OPS)})",
            )
        if not 0 < timeout_s <= 600:
            raise _fail(path, f"{where}.exec_ack_timeouts.{op}", "must be within 0..600 s")
    if arm.watchdog_s <= 0 or arm.lease_s <= 0:
        raise _fail(path, where, "watchdog_s and lease_s must be positive")
    if not 10 <= arm.max_speed_deg_s <= 10000:
        raise _fail(path, where, "max_speed_deg_s must be within 10..10000")
    gripper = (arm.gripper_closed_deg, arm.gripper_open_deg)
    if not all(-360.0 <= g <= 360.0 for g in gripper) or abs(gripper[1] - gripper[0]) < 1.0:
        raise _fail(
            path,
            where,
            f"gripper_closed_deg {gripper[0]:g} and gripper_open_deg {gripper[1]:g} must be "
            "within -360..360 and at least 1 deg apart",
        )
    if not 1 <= arm.enable_mode <= 80000:
        raise _fail(path, where, "enable_mode must be within 1..80000")
    if arm.sim_feedback_writers not in (1, 3):
        raise _fail(path, where, "sim_feedback_writers must be 1 or 3")
    if arm.sim_error_status == 1:
        raise _fail(path, where, "sim_error_status 1 is the normal value: use 0 or a bitfield")
    contact_problem = check_config(arm.contact)
    if contact_problem is not None:
        raise _fail(path, f"{where}.contact", contact_problem)
    dynamics_problem = arm.sim_dynamics.problem()
    if dynamics_problem is not None:
        raise _fail(path, f"{where}.sim_dynamics", dynamics_problem)


def parse_inventory(text: str, path: str = DEFAULT_INVENTORY) -> Inventory:
    """Parse and validate inventory text; ``path`` is only used in error messages."""
    try:
        raw = decode_toml(text)
    except TomlError as exc:
        raise InventoryError(f"{path}: {exc}") from None
    known = {
        "fleet",
        "zenoh",
        "dds",
        "coordinator",
        "defaults",
        "arms",
        "groups",
        "security",
        "principals",
        "ros2",
    }
    device_kinds = {kind.section: kind for kind in kinds().values()}
    known |= set(device_kinds)
    for key in raw:
        if key not in known:
            raise InventoryError(
                f"{path}: unknown section [{key}] (known: {', '.join(sorted(known))})"
            )
    if "fleet" not in raw:
        raise InventoryError(f'{path}: missing [fleet] section with name = "..."')
    fleet = _convert(raw["fleet"], FleetSection, path, "fleet")
    zenoh = _convert(raw.get("zenoh", {}), ZenohSection, path, "zenoh")
    dds = _convert(raw.get("dds", {}), DdsSection, path, "dds")
    coordinator = _convert(raw.get("coordinator", {}), CoordinatorSection, path, "coordinator")
    _check_finite(coordinator, path, "coordinator")
    if not (0 < coordinator.heartbeat_hz <= 1000 and 0 <= coordinator.sync_lead_s <= 5):
        raise InventoryError(
            f"{path}: coordinator: need 0 < heartbeat_hz <= 1000 and 0 <= sync_lead_s <= 5"
        )
    if coordinator.offline_after_s <= 0:
        raise InventoryError(f"{path}: coordinator: offline_after_s must be positive")
    defaults = raw.get("defaults", {})
    if not isinstance(defaults, dict):
        raise InventoryError(f"{path}: defaults: expected a table ([defaults])")
    if "id" in defaults:
        raise InventoryError(f"{path}: defaults: 'id' cannot have a default")
    _convert(defaults, ArmConfig, path, "defaults")
    arms_raw = raw.get("arms", {})
    has_devices = any(raw.get(section) for section in device_kinds)
    if not isinstance(arms_raw, dict) or not (arms_raw or has_devices):
        raise InventoryError(f"{path}: no arms: add at least one [arms.<id>] table")
    try:
        check_name("fleet", fleet.name)
    except KeyError_ as exc:
        raise InventoryError(f"{path}: fleet.name: {exc}") from None
    if not 0 <= dds.domain_id <= 232:
        raise InventoryError(f"{path}: dds.domain_id {brief(dds.domain_id)} is outside 0..232")
    for peer in dds.peers:
        problem = _network_name_problem("peer", peer)
        if problem is not None:
            raise InventoryError(f"{path}: dds.peers: {problem}")
    arms: dict[str, ArmConfig] = {}
    for arm_id, arm_raw in arms_raw.items():
        where = f"arms.{arm_id}"
        try:
            check_name("arm", arm_id)
        except KeyError_ as exc:
            raise InventoryError(f"{path}: {where}: {exc}") from None
        if not isinstance(arm_raw, dict):
            raise InventoryError(f"{path}: {where}: expected a table")
        if "id" in arm_raw:
            raise InventoryError(f"{path}: {where}: the id is the table's name; remove 'id'")
        merged = {**defaults, **arm_raw, "id": arm_id}
        merged.setdefault("agent", f"agent-{arm_id}")
        for table in ("contact", "exec_ack_timeouts"):  # merged field by field
            if isinstance(defaults.get(table), dict) and isinstance(arm_raw.get(table), dict):
                merged[table] = _merge(defaults[table], arm_raw[table])
        arm = _convert(merged, ArmConfig, path, where)
        _check_arm(arm, path)
        arms[arm_id] = arm
    _check_unique_topics(arms, dds.domain_id, path)
    devices = _parse_devices(raw, device_kinds, defaults, arms, path)
    groups = _parse_groups(raw.get("groups", {}), arms, path)
    security = _parse_security(raw.get("security", {}), path)
    principals = _parse_principals(raw.get("principals", {}), arms, path, devices)
    ros2 = _convert(raw["ros2"], Ros2Section, path, "ros2") if "ros2" in raw else None
    problem = ros2 and check_section(ros2, fleet.name, {*arms, *devices}, set(principals))
    if problem:
        raise InventoryError(f"{path}: ros2: {problem}")
    return Inventory(
        path=path,
        fleet=fleet.name,
        endpoints=zenoh.endpoints,
        datagram=Datagram(zenoh.datagram, zenoh.stop_dscp),
        domain_id=dds.domain_id,
        peers=dds.peers,
        arms=arms,
        groups=groups,
        coordinator=coordinator,
        security=security,
        principals=principals,
        devices=devices,
        ros2_section=ros2,
    )


def _parse_devices(
    raw: dict[str, Any],
    device_kinds: dict[str, DeviceKind],
    defaults: dict[str, Any],
    arms: dict[str, ArmConfig],
    path: str,
) -> dict[str, DeviceBase]:
    """Every ``[<section>.<id>]`` of every device kind; the network fields of ``[defaults]``
    apply to devices too."""
    inherited = {k: v for k, v in defaults.items() if k in NETWORK_FIELDS}
    devices: dict[str, DeviceBase] = {}
    for section, kind in device_kinds.items():
        tables = raw.get(section, {})
        if not isinstance(tables, dict):
            raise InventoryError(f"{path}: {section}: expected tables ([{section}.<id>])")
        for device_id, table in tables.items():
            where = f"{section}.{device_id}"
            try:
                check_name("device", device_id)
            except KeyError_ as exc:
                raise InventoryError(f"{path}: {where}: {exc}") from None
            if not isinstance(table, dict) or "id" in table:
                raise InventoryError(f"{path}: {where}: expected a table without 'id'")
            if device_id in arms or device_id in devices:
                raise InventoryError(f"{path}: {where}: the id {device_id!r} is already used")
            merged = {**inherited, **table, "id": device_id}
            mount = merged.get("mount")
            mounted_on = arms.get(mount) if isinstance(mount, str) else None
            merged.setdefault("agent", mounted_on.agent if mounted_on else f"agent-{device_id}")
            device = _convert(merged, kind.config, path, where)
            _check_finite(device, path, where)
            _check_network(device, path, where)
            problem = kind.check(device)
            mount = getattr(device, "mount", "")
            if problem is None and mount and mount not in arms:
                problem = f"mount {mount!r} is not an arm of this inventory"
            if problem is None and (device.watchdog_s <= 0 or device.lease_s <= 0):
                problem = "watchdog_s and lease_s must be positive"
            if problem is not None:
                raise _fail(path, where, problem)
            devices[device_id] = device
    return devices


def _parse_security(raw: Any, path: str) -> Security:
    section = _convert(raw, SecuritySection, path, "security")
    try:
        security = resolve(section, path)
    except ValueError as exc:
        raise InventoryError(f"{path}: security: {exc}") from None
    return security


def _parse_principals(
    raw: Any,
    arms: dict[str, ArmConfig],
    path: str,
    devices: dict[str, DeviceBase] | None = None,
) -> dict[str, Role]:
    """``[principals] name = "role"`` over the defaults, plus every arm's agent."""
    given = _convert(raw, dict[str, str], path, "principals")
    principals: dict[str, Role] = dict(DEFAULT_PRINCIPALS)
    for served in [*arms.values(), *(devices or {}).values()]:
        principals[served.agent] = "agent"
    for name, role in given.items():
        if principals.get(name) == "agent" and role != "agent":
            raise InventoryError(f"{path}: principals.{name}: it is an arm's agent")
        if role not in ROLES:
            raise InventoryError(
                f"{path}: principals.{name}: role {role!r} is not one of {', '.join(ROLES)}"
            )
        principals[name] = role  # type: ignore[assignment]
    for name in principals:
        try:
            check_name("principal", name)
        except KeyError_ as exc:
            raise InventoryError(f"{path}: principals: {exc}") from None
    return principals


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``over`` on top of ``base``, table by table (an arm overrides one contact threshold
    without repeating the others of ``[defaults.contact]``)."""
    out = dict(base)
    for key, value in over.items():
        old = out.get(key)
        out[key] = (
            _merge(old, value) if isinstance(old, dict) and isinstance(value, dict) else value
        )
    return out


def _check_unique_topics(arms: dict[str, ArmConfig], domain_id: int, path: str) -> None:
    """Two arms on the same domain and interface need different suffixes (spec, method 2)."""
    seen: dict[tuple[int, str, str], str] = {}
    for arm in arms.values():
        slot = (domain_id if arm.domain_id is None else arm.domain_id, arm.interface, arm.suffix)
        if slot in seen:
            raise InventoryError(
                f"{path}: arms.{arm.id}: suffix {arm.suffix!r} on interface {arm.interface!r} is "
                f"already used by arm {seen[slot]!r}; give each arm on one network its own suffix"
            )
        seen[slot] = arm.id


def _parse_groups(raw: Any, arms: dict[str, ArmConfig], path: str) -> dict[str, list[str]]:
    groups = _convert(raw, dict[str, list[str]], path, "groups")
    for name, members in groups.items():
        if name == "all" or name in arms:
            raise InventoryError(f"{path}: groups.{name}: the name is taken by 'all' or an arm")
        for member in members:
            if member not in arms:
                raise InventoryError(f"{path}: groups.{name}: unknown arm {member!r}")
    return dict(groups)


def load_inventory(path: str | Path = DEFAULT_INVENTORY) -> Inventory:
    """Read and validate ``path``."""
    try:
        text = read_text(path, "the inventory")
    except TomlError as exc:
        raise InventoryError(f"{path}: {exc}") from None
    return parse_inventory(text, str(path))
