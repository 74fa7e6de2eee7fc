"""The arm suffix rule against CycloneDDS itself: a participant of its own on loopback."""

from __future__ import annotations

from fleet.d1 import dds


def test_the_suffix_rule_is_cyclonedds_own(dds_domain: int) -> None:
    """Every character the rule accepts makes a topic CycloneDDS creates, every other one a
    topic it refuses (probed on a participant of its own, on loopback, no traffic)."""
    from cyclonedds.core import DDSException
    from cyclonedds.topic import Topic

    from fleet.d1.topics import suffix_problem

    channel = dds.DdsChannel(dds_domain, "lo")
    try:
        for code in range(1, 128):
            char = chr(code)
            legal = True
            try:
                Topic(channel.participant, dds.command_topic("_" + char), dds.ArmString_)
            except DDSException:
                legal = False
            assert (suffix_problem("_" + char) is None) is legal, repr(char)
    finally:
        channel.close()
