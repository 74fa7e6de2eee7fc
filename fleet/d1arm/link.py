"""The arms' DDS side, a part of the agent core's link (``fleet.devices.served.LinkPart``): one
feedback reader and one long-lived command writer per arm on the core's participant.

Created once, at start-up, on the core's thread: Unitree's SDK waits for discovery when a
writer is created, which a stop cannot afford. The core's relay thread waits over these
readers with every other kind's and calls each reader's taker directly: a ``partial`` bound
here, so a sample costs no lookup, and the feedback goes straight to the arms' server.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from functools import partial

from cyclonedds._clayer import ddspy_take, ddspy_write
from cyclonedds.core import DDSException, InstanceState, SampleState, ViewState
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from fleet.d1 import dds
from fleet.origin.directory import WriterDirectory
from fleet.origin.trust import SampleWriter

log = logging.getLogger("edge_agent.link")  # the name operators filter its warnings by

TAKE_BATCH = 64
ANY_SAMPLE = SampleState.Any | ViewState.Any | InstanceState.Any

FeedbackHandler = Callable[[str, bytes, float, "SampleWriter | None"], None]
"""(arm id, feedback text as UTF-8 bytes, monotonic receive time, the DDS writer and its host)."""
BadSampleHandler = Callable[[str, str], None]
"""(arm id, why the sample is not an ArmString_)."""


def _unserved(*_args: object) -> None:
    raise RuntimeError("the arms' link took a sample before it was given its server")


class ArmLink:
    """The ``ArmString_`` topics of every arm the agent serves (``suffixes``: arm -> topic
    suffix); ``serve`` names where their samples go, before the core's relay thread starts."""

    def __init__(
        self, participant: DomainParticipant, directory: WriterDirectory, suffixes: dict[str, str]
    ) -> None:
        self._directory = directory
        self._on_feedback: FeedbackHandler = _unserved
        self._on_bad_sample: BadSampleHandler = _unserved
        self._writers: dict[str, tuple[DataWriter, bool]] = {}
        self.readers: list[tuple[DataReader, Callable[[], None]]] = []
        self.write_failures = 0
        for arm, suffix in suffixes.items():
            fb = Topic(participant, dds.feedback_topic(suffix), dds.ArmString_)
            cmd = Topic(participant, dds.command_topic(suffix), dds.ArmString_)
            reader = DataReader(participant, fb, qos=dds.FEEDBACK_READER_QOS)
            self.readers.append((reader, partial(self._take, arm, reader)))
            writer = DataWriter(participant, cmd, qos=dds.COMMAND_WRITER_QOS)
            self._writers[arm] = (writer, bool(getattr(writer, "_use_version_2", False)))

    def serve(self, on_feedback: FeedbackHandler, on_bad_sample: BadSampleHandler) -> None:
        """Where feedback and malformed samples go (at start-up, before the relay thread)."""
        self._on_feedback, self._on_bad_sample = on_feedback, on_bad_sample

    def write(self, arm: str, text: str) -> bool:
        """Write one command string; False if DDS refused it (treat as "maybe sent")."""
        writer, version_2 = self._writers[arm]
        ret = ddspy_write(writer._ref, dds.arm_string_sample(text, version_2))
        if ret < 0:
            self.write_failures += 1
            log.warning("DDS write to arm %s failed: %s", arm, DDSException(ret, "write"))
            return False
        return True

    def _take(self, arm: str, reader: DataReader) -> None:
        taken = ddspy_take(reader._ref, ANY_SAMPLE, TAKE_BATCH)
        if isinstance(taken, int):
            raise DDSException(taken, f"taking feedback of arm {arm}")
        now = time.monotonic()
        for serialized, info in taken:
            if not info.valid_data:  # a writer went away: no data, only a state change
                continue
            try:
                text = dds.arm_string_bytes(serialized)
            except ValueError as exc:
                self._on_bad_sample(arm, str(exc))
                continue
            writer = self._directory.identify(reader, int(info.publication_handle))
            self._on_feedback(arm, text, now, writer)
