"""rmw_zenoh's wire contract (ros2/rmw_zenoh ``docs/design.md``), pure: no I/O, no clock.

- Data key: ``<domain_id>/<fully qualified name, outer slashes stripped>/<DDS type>/<RIHS01 hash>``
  (``0/lab/a1/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_a13e...``); a service's
  queryable lives on the same form with the service type (``std_srvs::srv::dds_::Trigger_``).
- Liveliness tokens (hermetic ``@ros2_lv`` prefix, ``/`` in names mangled to ``%``), a node:
  ``@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>``; a publisher (MP) or
  service server (SS): ``@ros2_lv/<domain>/<zid>/<nid>/<eid>/MP/<enclave>/<namespace>/<node>/
  <topic>/<type>/<hash>/<qos>``.
- QoS in a token: ``reliability:durability:history,depth:deadline_s,ns:lifespan_s,ns:
  liveliness,lease_s,lease_ns``, each field empty when it equals rmw_zenoh's default (reliable,
  volatile, keep last 42, infinite, automatic), else the rmw enum's number
  (``liveliness_utils.cpp::qos_to_keyexpr``, ``qos.cpp``); transient local, depth 1:
  ``:1:,1:,:,:,,``.
- Attachment of every sample, request and reply (33 bytes, zenoh-ext serializer): int64 LE
  sequence number (per publisher, from 1), int64 LE source timestamp (ns since the epoch), the
  GID's length as one LEB128 byte (16), the 16-byte GID.

Type hashes are constants here (their REP-2016 RIHS01 values); ``tests/unit/test_ros2_contract.py``
checks them against an independent implementation (rosbags' ``hash_rihs01``) and the public
values found in ROS installs' generated code.
"""

from __future__ import annotations

import hashlib
import re
import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SERVICE = "NN", "MP", "SS"
ATTACHMENT_BYTES = 33
GID_BYTES = 16

RELIABLE, BEST_EFFORT = 1, 2
"""rmw_qos_reliability_policy_e."""
TRANSIENT_LOCAL, VOLATILE = 1, 2
"""rmw_qos_durability_policy_e."""
KEEP_LAST = 1
DEFAULT_DEPTH = 42
"""rmw_zenoh's defaults (``qos.cpp``): reliable, volatile, keep last 42."""


@dataclass(frozen=True)
class RosType:
    """A ROS interface type on the wire: its ROS name, DDS name and RIHS01 hash."""

    name: str
    dds: str
    hash: str


def _dds(name: str) -> str:
    package, kind, leaf = name.split("/")
    return f"{package}::{kind}::dds_::{leaf}_"


def _type(name: str, digest: str) -> RosType:
    return RosType(name, _dds(name), f"RIHS01_{digest}")


JOINT_STATE = _type(
    "sensor_msgs/msg/JointState", "a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
)
STRING = _type(
    "std_msgs/msg/String", "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
)
TF_MESSAGE = _type(
    "tf2_msgs/msg/TFMessage", "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
)
DIAGNOSTIC_ARRAY = _type(
    "diagnostic_msgs/msg/DiagnosticArray",
    "5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
)
TRIGGER = _type(
    "std_srvs/srv/Trigger", "eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f"
)
"""A service's token and key carry the service type (rmw_zenoh strips ``Response_`` from the
response type's name: ``std_srvs::srv::dds_::Trigger_``) and the service's own hash."""

HUMBLE_HASH = "TypeHashNotSupported"
"""What rmw_zenoh on ROS 2 Humble (no REP-2016 type hashes) puts where the RIHS01 hash goes,
in data keys and tokens alike (``0/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported``)."""
DISTROS = ("jazzy", "humble")
"""``jazzy``: RIHS01 hashes (Jazzy, Kilted, Rolling); ``humble``: none."""


def for_distro(rtype: RosType, distro: str) -> RosType:
    """``rtype`` as ``distro``'s rmw_zenoh spells it."""
    if distro == "humble":
        return RosType(rtype.name, rtype.dds, HUMBLE_HASH)
    return rtype


_TOKEN = re.compile(r"^[A-Za-z][A-Za-z0-9_]*\Z")


class NameError_(ValueError):  # noqa: N801 - a bad ROS name, not the builtin NameError
    """A ROS namespace or name that is not valid (tokens of letters, digits, ``_``)."""


def check_namespace(namespace: str) -> str:
    """An absolute ROS namespace: ``/`` and tokens that start with a letter, no ``__``."""
    parts = namespace.split("/")
    if (
        not namespace.startswith("/")
        or namespace.endswith("/")
        and namespace != "/"
        or "__" in namespace
        or any(not _TOKEN.match(p) for p in parts[1:] if namespace != "/")
    ):
        raise NameError_(
            f"ROS namespace {namespace!r} is not valid: use /token/token with tokens of letters, "
            "digits and '_' (starting with a letter, no '__')"
        )
    return namespace


def default_namespace(fleet: str, unit: str) -> str:
    """``/<fleet>/<unit>``, with ``-`` (legal in fleet ids, not in ROS names) as ``_``."""
    return f"/{fleet.replace('-', '_')}/{unit.replace('-', '_')}"


def mangle(name: str) -> str:
    """``/`` -> ``%`` (a token chunk may hold no ``/``); ``%`` for the empty name."""
    return name.replace("/", "%") if name else "%"


def topic_key(domain_id: int, fqn: str, rtype: RosType) -> str:
    """The data key of topic or service ``fqn`` (fully qualified: ``/lab/a1/joint_states``)."""
    return f"{domain_id}/{fqn.strip('/')}/{rtype.dds}/{rtype.hash}"


def qos_keyexpr(
    reliability: int = RELIABLE,
    durability: int = VOLATILE,
    depth: int = DEFAULT_DEPTH,
    history: int = KEEP_LAST,
) -> str:
    """The QoS part of a token (deadline, lifespan, liveliness: rmw_zenoh's defaults)."""

    def field(value: int, default: int) -> str:
        return "" if value == default else str(value)

    return (
        f"{field(reliability, RELIABLE)}:{field(durability, VOLATILE)}:"
        f"{field(history, KEEP_LAST)},{field(depth, DEFAULT_DEPTH)}:,:,:,,"
    )


@dataclass(frozen=True)
class Node:
    """One ROS node of a Zenoh session (``zid``: the session id as Zenoh prints it)."""

    domain_id: int
    zid: str
    node_id: int
    namespace: str
    name: str
    enclave: str = "/"

    def _prefix(self, entity_id: int, kind: str) -> str:
        ns = mangle(self.namespace if self.namespace != "/" else "")
        return (
            f"{ADMIN_SPACE}/{self.domain_id}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(self.enclave if self.enclave != '/' else '')}/{ns}/{self.name}"
        )

    def token(self) -> str:
        """The node's own (NN) token."""
        return self._prefix(self.node_id, NODE)

    def entity_token(self, entity_id: int, kind: str, fqn: str, rtype: RosType, qos: str) -> str:
        """A publisher's (MP) or service server's (SS) token."""
        return f"{self._prefix(entity_id, kind)}/{mangle(fqn)}/{rtype.dds}/{rtype.hash}/{qos}"


def gid_of(token: str) -> bytes:
    """An entity's 16-byte GID, derived from its token as rmw_zenoh does (it hashes the token
    with XXH3-128; any stable 16 bytes serve: the GID is opaque to every reader)."""
    return hashlib.sha256(token.encode()).digest()[:GID_BYTES]


@dataclass(frozen=True)
class Attachment:
    """The attachment of a sample, a service request or its reply."""

    sequence: int
    stamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        """33 bytes: seq, timestamp (int64 LE), GID length (16) and the GID."""
        return struct.pack("<qqB16s", self.sequence, self.stamp_ns, GID_BYTES, self.gid)


class AttachmentError(ValueError):
    """Bytes that are not an rmw_zenoh attachment."""


def decode_attachment(data: bytes | None) -> Attachment:
    """The attachment in ``data``; AttachmentError for a missing or malformed one."""
    if data is None:
        raise AttachmentError("no attachment")
    if len(data) != ATTACHMENT_BYTES:
        raise AttachmentError(f"{len(data)} bytes, not {ATTACHMENT_BYTES}")
    sequence, stamp_ns, size, gid = struct.unpack("<qqB16s", data)
    if size != GID_BYTES:
        raise AttachmentError(f"GID length {size}, not {GID_BYTES}")
    if sequence < 0 or stamp_ns < 0:
        raise AttachmentError("negative sequence number or timestamp")
    return Attachment(sequence, stamp_ns, gid)
