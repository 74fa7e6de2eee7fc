"""Fuzz target: ``decode_command``, the D1 command decoder (what the arm's service does; the
simulator runs it on every string the agent writes).

Property: any input gives ``(seq, command)`` or ``MalformedMessage``/``InvalidCommand``, never
another exception; a command that decodes passes ``validate_command`` (no out-of-range command
can come out of the decoder), and re-encoded with its seq (when a caller may use that seq) it
decodes to the same command.
"""

from __future__ import annotations

from fuzz.common import instrumented, main, texts

with instrumented():
    from fleet.d1 import protocol as p
    from fleet.d1.errors import InvalidCommand, MalformedMessage


def check(data: bytes) -> None:
    """The property, for one input."""
    for text in texts(data):
        try:
            seq, command = p.decode_command(text)
        except (MalformedMessage, InvalidCommand):
            continue
        p.validate_command(command)  # InvalidCommand here breaks the property
        try:
            p.check_seq(seq)
        except InvalidCommand:
            continue  # seq 10 or negative: decodable (the arm's business), not ours to send
        again = p.decode_command(p.encode_command(command, seq))
        assert again == (seq, command), (again, seq, command)


def seeds() -> list[bytes]:
    """The spec's example commands (the golden table), and a few edge values."""
    from testkit.golden_d1 import GOLDEN_COMMANDS

    texts_ = [text for text, _ in GOLDEN_COMMANDS]
    texts_ += [
        '{"seq":65535,"address":1,"funcode":1,"data":{"id":6,"angle":65.0,"delay_ms":0}}',
        '{"seq":1,"address":1,"funcode":2,"data":{"mode":0,"angle0":-135,"angle1":90,'
        '"angle2":-90,"angle3":135,"angle4":-90,"angle5":135,"angle6":0.5}}',
        '{"seq":2,"address":1,"funcode":5,"data":{"mode":80000}}',
        '{"seq":3,"address":1,"funcode":4,"data":{"id":0,"mode":0}}',
    ]
    return [t.encode() for t in texts_]


if __name__ == "__main__":
    main(check)
