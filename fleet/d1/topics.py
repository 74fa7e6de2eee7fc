"""The D1 service's DDS topic names, and what makes a topic suffix legal. Pure (no DDS import:
the inventory checks suffixes without loading CycloneDDS).

The spec's multi-arm method 2 appends a suffix to every topic of an arm (``rt/arm_Command_1``);
it only shows ``_1``, and an arm's driver code takes any string there. What limits a suffix is
DDS: CycloneDDS (the DDS of the arm's unitree_sdk2, and ours) accepts printable ASCII in a topic
name except space and ``" # $ ' * ? [ ]`` (its pattern and quoting characters; probed character
by character), and RTPS limits a topic name to 256 characters.
"""

from __future__ import annotations

import re

COMMAND_TOPIC = "rt/arm_Command"
FEEDBACK_TOPIC = "rt/arm_Feedback"

MAX_TOPIC_NAME = 256
MAX_SUFFIX = MAX_TOPIC_NAME - max(len(COMMAND_TOPIC), len(FEEDBACK_TOPIC))

_TOPIC_CHARS = re.compile(r"^[!%&()+,\-./0-9:;<=>@A-Z\\^_`a-z{|}~]*\Z")  # \Z: "$" takes a "\n"


def command_topic(suffix: str) -> str:
    """``rt/arm_Command<suffix>``, e.g. ``rt/arm_Command_1``."""
    return COMMAND_TOPIC + suffix


def feedback_topic(suffix: str) -> str:
    """``rt/arm_Feedback<suffix>``."""
    return FEEDBACK_TOPIC + suffix


def suffix_problem(suffix: str) -> str | None:
    """Why ``suffix`` does not make legal DDS topic names, or None (``""`` is legal)."""
    if len(suffix) > MAX_SUFFIX or not _TOPIC_CHARS.match(suffix):
        return (
            f"suffix {suffix[:40]!r} does not make a legal DDS topic name: use at most "
            f"{MAX_SUFFIX} printable ASCII characters without spaces or \" # $ ' * ? [ ] "
            "(e.g. '_1', '1', '-a')"
        )
    return None
