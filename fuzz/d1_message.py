"""Fuzz target: ``decode_message``, the D1 feedback decoder (strings from the arm's DDS topic).

Property: any input gives a ``Decoded`` or ``MalformedMessage``, never another exception; a
decoded angle report has seven finite angles and a motor report seven flags (the tracker and
the contact detector index them blindly).
"""

from __future__ import annotations

import math

from fuzz.common import instrumented, main, texts

with instrumented():
    from fleet.d1 import protocol as p
    from fleet.d1.errors import MalformedMessage
    from fleet.d1.limits import JOINT_COUNT


def check(data: bytes) -> None:
    """The property, for one input."""
    for text in texts(data):
        try:
            decoded = p.decode_message(text)
        except MalformedMessage:
            continue
        message = decoded.message
        if isinstance(message, p.JointAngles):
            angles = message.angles_deg
            assert len(angles) == JOINT_COUNT and all(math.isfinite(a) for a in angles), message
        elif isinstance(message, p.MotorStatus):
            assert len(message.motors_ok) == JOINT_COUNT, message
        else:
            assert isinstance(message, (p.D1Status, p.ReceiveAck, p.ExecuteAck)), message


def seeds() -> list[bytes]:
    """The spec's example messages (the golden table), and an ack of another seq."""
    from testkit.golden_d1 import GOLDEN_COMMANDS, GOLDEN_MESSAGES

    texts_ = [text for text, _ in GOLDEN_MESSAGES] + [text for text, _ in GOLDEN_COMMANDS]
    texts_.append('{"seq":12,"address":3,"funcode":1,"data":{"recv_status":1},"x":1}')
    return [t.encode() for t in texts_]


if __name__ == "__main__":
    main(check)
