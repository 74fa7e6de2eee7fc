"""The agent's DDS side: one participant for its (domain, interface), one long-lived command
writer and one feedback reader per arm, and the thread that takes feedback.

The reader thread waits on a WaitSet (feedback on any arm, or the shutdown guard) and hands
every string to ``on_feedback``; it never creates or deletes entities. Writers are created once:
Unitree's SDK waits for discovery when a writer is created, which a stop cannot afford.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from cyclonedds.core import (
    DDSException,
    GuardCondition,
    InstanceState,
    ReadCondition,
    SampleState,
    ViewState,
    WaitSet,
)
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from fleet.d1 import dds

log = logging.getLogger("edge_agent.link")

_ANY = SampleState.Any | ViewState.Any | InstanceState.Any
TAKE_BATCH = 64

FeedbackHandler = Callable[[str, str, float], None]
"""(arm id, feedback text, monotonic receive time)."""


class DdsLink:
    """DDS endpoints for every arm the agent serves on one domain and interface."""

    def __init__(
        self,
        domain_id: int,
        interface: str,
        peers: tuple[str, ...],
        suffixes: dict[str, str],
        on_feedback: FeedbackHandler,
    ) -> None:
        self._channel = dds.DdsChannel(domain_id, interface, peers)
        participant = self._channel.participant
        self._on_feedback = on_feedback
        self._guard = GuardCondition(participant)
        self._waitset = WaitSet(participant)
        self._waitset.attach(self._guard)
        self._readers: list[tuple[str, DataReader]] = []
        self._writers: dict[str, DataWriter] = {}
        self.write_failures = 0
        for arm, suffix in suffixes.items():
            fb = Topic(participant, dds.feedback_topic(suffix), dds.ArmString_)
            cmd = Topic(participant, dds.command_topic(suffix), dds.ArmString_)
            reader = DataReader(participant, fb, qos=dds.FEEDBACK_READER_QOS)
            self._waitset.attach(ReadCondition(reader, _ANY))
            self._readers.append((arm, reader))
            self._writers[arm] = DataWriter(participant, cmd, qos=dds.COMMAND_WRITER_QOS)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="dds-feedback", daemon=True)

    def start(self) -> None:
        """Start taking feedback."""
        self._thread.start()

    def write(self, arm: str, text: str) -> bool:
        """Write one command string; False if DDS refused it (treat as "maybe sent")."""
        try:
            self._writers[arm].write(dds.ArmString_(text))
        except DDSException as exc:
            self.write_failures += 1
            log.warning("DDS write to arm %s failed: %s", arm, exc)
            return False
        return True

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._waitset.wait(duration(milliseconds=200))
                for arm, reader in self._readers:
                    samples = reader.take(N=TAKE_BATCH)
                    if not samples:
                        continue
                    now = time.monotonic()
                    for sample in samples:
                        text = getattr(sample, "data_", None)
                        if text is not None:  # InvalidSample: a writer went away
                            self._on_feedback(arm, text, now)
        except BaseException:
            log.exception("DDS feedback thread failed")
            raise

    def close(self) -> None:
        """Stop the thread, then delete the participant (idempotent)."""
        self._stop.set()
        self._guard.set(True)
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._channel.close()
