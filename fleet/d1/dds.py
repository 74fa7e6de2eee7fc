"""The DDS side of the D1 service: the ArmString_ type, topic names, QoS and CycloneDDS config.

This is our ``ChannelFactory::Init(domainId, networkInterface)``: ``open_participant`` takes a
domain id and a network interface name and builds the CycloneDDS configuration from them, so the
two multi-arm methods of the spec both work:
- topic suffix: several arms on one network, each with its own ``rt/arm_Command_<n>`` topics;
- NIC binding: one arm per network card; one process per card, bound to that card only.

Discovery has two modes, as Unitree's SDK reads its arguments:
- unicast (the default): multicast off and an explicit peer list, which is what the tests and
  the demo need on loopback and what a real arm network (``192.168.123.0/24``) works with too;
- multicast (``multicast = true`` in the inventory): CycloneDDS's own multicast discovery, as
  ``ChannelFactory::Init`` does; peers, if any, are still probed. For real arm networks only.
An empty interface name means "let CycloneDDS choose one", as ``ChannelFactory::Init(domain)``
without an interface does; a name the host does not have is a ``NetworkInterfaceError``.

(No ``from __future__ import annotations`` here: CycloneDDS resolves the IDL field types at
run time and cannot resolve string annotations.)
"""

import socket
import struct
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.util import duration

from fleet.d1.errors import NetworkInterfaceError
from fleet.d1.topics import COMMAND_TOPIC as COMMAND_TOPIC  # re-exported: topics.py is pure
from fleet.d1.topics import FEEDBACK_TOPIC as FEEDBACK_TOPIC
from fleet.d1.topics import command_topic as command_topic
from fleet.d1.topics import feedback_topic as feedback_topic

MAX_PARTICIPANTS_PER_HOST = 60
"""Unicast discovery probes this many participant indices per peer; the default of 9 is too few
for a host running a simulated fleet (one participant per simulator and agent process)."""


@dataclass
class ArmString_(IdlStruct, typename="unitree_arm::msg::dds_::ArmString_"):  # noqa: N801
    """``unitree_arm::msg::dds_::ArmString_``: one JSON string in ``data_`` (default ``""``:
    helpers such as unitree-dds-wrapper's Publisher construct the type without arguments)."""

    data_: str = ""


_PLAIN_ENCAPSULATIONS = {0x0000: ">I", 0x0001: "<I", 0x0006: ">I", 0x0007: "<I"}
"""CDR and plain XCDR2, big and little endian: for a final struct of one string, both lay it out
as a 4-byte length (with the NUL) and the bytes. Anything else goes through the IDL machinery."""


def arm_string_bytes(serialized: bytes) -> bytes:
    """The ``data_`` of one serialized ArmString_ sample, as bytes without the NUL.

    The agent's hot path: the binding's generic IDL deserialiser cost 12 us a sample, this a
    fraction of it. The text is not decoded here: the D1 codec decodes it and counts invalid
    UTF-8 as a malformed message. Raises ValueError when the sample is not an ArmString_.
    """
    if len(serialized) < 9:  # the 4-byte header, a length and at least the NUL
        raise ValueError(f"not an ArmString_ sample ({len(serialized)} bytes)")
    layout = _PLAIN_ENCAPSULATIONS.get(int.from_bytes(serialized[:2], "big"))
    if layout is None:
        try:
            return ArmString_.deserialize(serialized).data_.encode()
        except Exception as exc:  # noqa: BLE001 - the binding raises anything on a hostile one
            raise ValueError(f"not an ArmString_ sample ({type(exc).__name__}: {exc})") from None
    (size,) = struct.unpack_from(layout, serialized, 4)
    end = 8 + size
    if size < 1 or end > len(serialized) or serialized[end - 1] != 0:
        raise ValueError(
            f"not an ArmString_ sample (string of {size} bytes in a {len(serialized)} byte sample)"
        )
    return serialized[8 : end - 1]


def arm_string_sample(text: str, version_2: bool = False) -> bytes:
    """``text`` as one serialized ArmString_ sample (little-endian CDR, or plain XCDR2), padded
    to 4 bytes as the binding's ``DataWriter.write`` pads it: byte for byte what the binding
    would write, at a twentieth of its cost (its generic IDL serialiser took 12 us a command,
    paid once per arm by a fleet stop)."""
    data = text.encode()
    header = b"\x00\x07\x00\x00" if version_2 else b"\x00\x01\x00\x00"
    sample = header + struct.pack("<I", len(data) + 1) + data + b"\x00"
    return sample.ljust((len(sample) + 3) & ~3, b"\x00")


# Commands: reliable, so a reliable reader on the arm gets retransmissions, and a best-effort
# reader (the DDS default, and what the arm's reader may well be) still matches. Keep-last 8:
# a burst of commands is not dropped before it is sent, yet writes never block for long.
# Volatile durability: an arm that (re)joins late must never execute a stale command.
COMMAND_WRITER_QOS = Qos(
    Policy.Reliability.Reliable(duration(milliseconds=100)),
    Policy.History.KeepLast(8),
    Policy.Durability.Volatile,
)

# Feedback: the newest sample matters; best effort matches any writer QoS the arm may use.
# Depth 64 absorbs a burst (angles, status, motors and acks arrive together) between takes.
FEEDBACK_READER_QOS = Qos(
    Policy.Reliability.BestEffort,
    Policy.History.KeepLast(64),
    Policy.Durability.Volatile,
)

# The simulated arm's side mirrors the two above.
COMMAND_READER_QOS = Qos(
    Policy.Reliability.Reliable(duration(milliseconds=100)),
    Policy.History.KeepLast(32),
    Policy.Durability.Volatile,
)
FEEDBACK_WRITER_QOS = Qos(
    Policy.Reliability.BestEffort,
    Policy.History.KeepLast(8),
    Policy.Durability.Volatile,
)


def cyclonedds_config(
    interface: str, peers: list[str] | tuple[str, ...], multicast: bool = False
) -> str:
    """CycloneDDS XML: bound to ``interface`` (``""``: CycloneDDS chooses), unicast ``peers``,
    multicast discovery only with ``multicast``."""
    peer_xml = "".join(f"<Peer address={quoteattr(p)}/>" for p in peers)
    interfaces = (
        f"<Interfaces><NetworkInterface name={quoteattr(interface)}/></Interfaces>"
        if interface
        else ""
    )
    # "default" is CycloneDDS's own choice (multicast where the interface supports it), what a
    # Unitree SDK program without a configuration gets.
    allow_multicast = "default" if multicast else "false"
    return (
        "<CycloneDDS><Domain id='any'>"
        f"<General>{interfaces}<AllowMulticast>{allow_multicast}</AllowMulticast></General>"
        "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
        f"<MaxAutoParticipantIndex>{MAX_PARTICIPANTS_PER_HOST}</MaxAutoParticipantIndex>"
        f"<Peers>{peer_xml}</Peers></Discovery>"
        "</Domain></CycloneDDS>"
    )


def check_interface(interface: str) -> None:
    """Raise NetworkInterfaceError unless ``interface`` is empty or a network interface of this
    host (checked before CycloneDDS, which fails with "Non specific error")."""
    if not interface:
        return
    names = [name for _index, name in socket.if_nameindex()]
    if interface not in names:
        raise NetworkInterfaceError(
            f"network interface {interface!r} does not exist on this host (it has: "
            f"{', '.join(names) or 'none'}); set the arm's `interface` in the inventory to one of "
            'them, or to "" to let DDS choose one'
        )


LOOPBACK_PEERS = ("127.0.0.1",)


class DdsChannel:
    """One DDS participant for one (domain, network interface): create it once, at start-up,
    on one thread (CycloneDDS Python races when entities are created from several threads)."""

    def __init__(
        self,
        domain_id: int,
        interface: str = "lo",
        peers: tuple[str, ...] = LOOPBACK_PEERS,
        multicast: bool = False,
    ) -> None:
        self.domain_id = domain_id
        self.interface = interface
        check_interface(interface)
        # The Domain object carries the config; it must exist before the participant.
        self._domain = Domain(domain_id, cyclonedds_config(interface, peers, multicast))
        self.participant = DomainParticipant(domain_id)

    def close(self) -> None:
        """Delete the participant and every entity under it (idempotent)."""
        participant, self.participant = self.participant, None  # type: ignore[assignment]
        if participant is not None:
            # The binding has no public delete; its finaliser deletes the participant and, in
            # the DDS core, every reader, writer and topic under it. Safe to call once.
            participant.__del__()
        self._domain = None  # type: ignore[assignment]
