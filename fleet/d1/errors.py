"""Errors of the D1 codec.

Hierarchy::

    ProtocolError                 base of everything the codec raises
    +-- InvalidCommand            we tried to build a command the arm must not receive (a bug
    |   |                         or a caller's bad input; raised before anything is encoded)
    |   +-- InvalidJoint          a joint id outside 0..6
    +-- MalformedMessage          the arm (or someone on its topic) sent text we cannot decode
        +-- UnknownMessage        well-formed JSON, but an address/funcode the spec does not define

    NetworkInterfaceError         (a ValueError, not a protocol error) the inventory names a
                                  network interface this host does not have
"""

from __future__ import annotations


class ProtocolError(Exception):
    """Base class of the D1 codec's errors."""


class InvalidCommand(ProtocolError, ValueError):
    """A command that must never reach the arm: bad joint id, out-of-range or non-finite angle.

    ``seq`` is set when the command was decoded from text that carried one.
    """

    seq: int | None = None


class InvalidJoint(InvalidCommand):
    """A joint id outside 0..6 (the real arm acks these, then stops its angle feed)."""


class MalformedMessage(ProtocolError):
    """Text that is not a valid D1 message. ``seq`` is set when the envelope carried one."""

    seq: int | None = None


class UnknownMessage(MalformedMessage):
    """A well-formed message whose address/funcode pair the spec does not define."""

    def __init__(self, address: int, funcode: int) -> None:
        super().__init__(f"unknown D1 message address={address} funcode={funcode}")
        self.address = address
        self.funcode = funcode


class NetworkInterfaceError(ValueError):
    """The network interface a DDS participant is to bind to does not exist on this host.

    CycloneDDS itself only says "Non specific error" (and prints the name on stderr): this names
    the interface, the ones the host has, and the fix."""
