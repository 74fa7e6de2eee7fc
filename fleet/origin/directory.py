"""Who wrote a sample: the DDS writer's handle and the host of its participant.

The D1's own driver publishes ``rt/arm_Feedback`` from three services (seed 000:
marm_communication, marm_control and marm_controller, three processes on the arm's card, so
three DDS participants): the agent cannot trust only the first writer it hears. It trusts the
robot's *host* instead (``trust.py`` decides, for an arm's feedback and a device's state
alike), and this module says which host a writer is on.

CycloneDDS (which Unitree's SDK is built on) announces every participant with the properties
``__Hostname`` and ``__NetworkAddresses`` (``udp/192.168.123.100:7410@1``). The host of a writer
is its participant's host name and addresses without ports, e.g.
``arm-1 udp/192.168.123.100``. A participant in the agent's own process reports
``localprocess``. A participant without these properties (another DDS vendor) has host None:
such writers are one group, "a host we cannot name".

Lookups run on the relay thread when a writer is first seen (one ``get_matched_publication_
data`` call and one read of the participant built-in reader, both in the C core, no entity
created), then the answer is cached by the writer's handle.
"""

from __future__ import annotations

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant, DcpsParticipant
from cyclonedds.core import DDSException, Policy
from cyclonedds.sub import DataReader

from fleet.origin.trust import SampleWriter

RESOLVE_TRIES = 50
"""Samples of a writer whose participant is not known yet (discovery still under way) before
its host is taken as unknown for good."""


class WriterDirectory:
    """Maps a writer's instance handle to a ``SampleWriter`` (relay thread only)."""

    def __init__(self, participant: object) -> None:
        self._participants = BuiltinDataReader(participant, BuiltinTopicDcpsParticipant)  # type: ignore[arg-type]
        self._hosts: dict[object, str | None] = {}
        self._writers: dict[int, SampleWriter] = {}
        self._tries: dict[int, int] = {}

    def identify(self, reader: DataReader, handle: int) -> SampleWriter:
        """The writer ``handle`` matched with ``reader``, with its host when known."""
        known = self._writers.get(handle)
        if known is not None:
            return known
        host, resolved = self._host_of(reader, handle)
        writer = SampleWriter(handle, host)
        tries = self._tries.get(handle, 0) + 1
        if resolved or tries >= RESOLVE_TRIES:
            self._writers[handle] = writer
            self._tries.pop(handle, None)
        else:
            self._tries[handle] = tries
        return writer

    def _host_of(self, reader: DataReader, handle: int) -> tuple[str | None, bool]:
        try:
            endpoint = reader.get_matched_publication_data(handle)
        except DDSException:
            endpoint = None  # the writer went away meanwhile
        if endpoint is None:
            return None, False
        participant = endpoint.participant_key
        if participant not in self._hosts:
            for sample in self._participants.take(N=256):
                if isinstance(sample, DcpsParticipant) and sample.qos is not None:
                    self._hosts[sample.key] = host_of(sample.qos)
        if participant not in self._hosts:
            return None, False
        return self._hosts[participant], True


def host_of(qos: object) -> str | None:
    """``hostname addresses`` from a participant's CycloneDDS properties, None without them."""
    properties: dict[str, str] = {}
    for policy in qos:  # type: ignore[attr-defined]
        if isinstance(policy, Policy.Property):
            properties[policy.key] = policy.value
    name, addresses = properties.get("__Hostname"), properties.get("__NetworkAddresses")
    if name is None and addresses is None:
        return None
    hosts = sorted({a.rsplit(":", 1)[0] if "/" in a else a for a in (addresses or "").split(",")})
    return f"{name or '?'} {','.join(h for h in hosts if h)}"
