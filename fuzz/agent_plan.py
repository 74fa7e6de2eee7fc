"""Fuzz target: the agent's command planning (``fleet.d1arm.commands.plan``) on a decoded command
payload, against an arm tracker in a state chosen by the input.

Input: byte 0 picks the tracker's state (stopped or not, power on/off/unknown, stop action,
fresh or stale feedback), bytes 1..7 the measured angles it was fed (a valid angle report,
possibly a hair outside the documented ranges, as real arms report), the rest is the
``arm/<arm>/cmd`` payload.

Property: the payload decodes or gives ``PayloadError``; ``plan`` gives ``Refusal`` or a
``Plan`` whose every D1 command passes ``validate_command``, with angles inside the joint
ranges (nothing out of range ever reaches DDS); a hold targets the measured pose clamped to the
ranges; a stopped, powered-off or unfed arm gets no motion; under a ``hold`` stop nothing that
lets the arm fall.
"""

from __future__ import annotations

from fuzz.common import instrumented, main

with instrumented():
    from fleet.d1 import protocol as p
    from fleet.d1.limits import JOINT_COUNT, JOINT_RANGE_DEG
    from fleet.d1arm.commands import Plan, plan
    from fleet.d1arm.holds import clamp_to_limits
    from fleet.d1arm.tracker import ArmTracker
    from fleet.devices.driver import Refusal
    from fleet.inventory import ArmConfig
    from fleet.wire import payloads
    from fleet.wire.messages import ErrorCode

ACTIONS = ("hold", "unload", "power_off")
POWER = (None, True, False)
CONFIGS = {action: ArmConfig(id="a1", stop_action=action) for action in ACTIONS}
HEADER = 1 + JOINT_COUNT


def tracker_from(header: bytes) -> tuple[ArmTracker, float]:
    """A tracker fed one valid angle report at t=0, in the state ``header`` describes, and the
    time to plan at (0.0: fresh feedback, 1.0: stale)."""
    flags = header[0]
    config = CONFIGS[ACTIONS[(flags >> 3) % 3]]
    tracker = ArmTracker(config)
    # 0..255 -> -153..+153 deg: inside and a little outside every joint's range
    angles = tuple((b - 128) * 1.2 for b in header[1:HEADER])
    text = p.encode_message(p.JointAngles(angles))
    assert tracker.on_feedback(text, now=0.0) is not None
    tracker.update_link(0.0)
    if flags & 1:
        tracker.safety.latch("fuzz", "fuzz", "", 0.0, 0, config.stop_action)
    tracker.powered = POWER[(flags >> 1) % 3]
    now = 1.0 if flags & 0x40 else 0.0
    tracker.update_link(now)
    return tracker, now


def check(data: bytes) -> None:
    """The property, for one input."""
    if len(data) < HEADER:
        return
    try:
        command = payloads.COMMAND.decode(data[HEADER:])
    except payloads.PayloadError:
        return
    tracker, now = tracker_from(data[:HEADER])
    try:
        result = plan(command, tracker, now)
    except Refusal as exc:
        assert exc.code in ErrorCode.__members__.values(), exc
        return
    _check_plan(result, tracker)


def _check_plan(result: Plan, tracker: ArmTracker) -> None:
    assert all(0 <= i < len(result.commands) for i in result.holds), result
    measured = tracker.angles_deg
    assert measured is not None
    for index, command in enumerate(result.commands):
        p.validate_command(command)
        angles: tuple[float, ...] = ()
        if isinstance(command, p.SetAllAngles):
            angles = command.angles_deg
        elif isinstance(command, p.SetJointAngle):
            angles = (command.angle_deg,)
            assert 0 <= command.joint < JOINT_COUNT, command
        for joint, angle in enumerate(angles):
            low, high = JOINT_RANGE_DEG[command.joint if len(angles) == 1 else joint]
            assert low <= angle <= high, (command, result)
        is_hold = index in result.holds
        if is_hold:
            assert command == p.SetAllAngles(clamp_to_limits(measured), 0), (command, measured)
        moves = isinstance(command, (p.SetJointAngle, p.ReturnToZero)) or (
            isinstance(command, p.SetAllAngles) and not is_hold
        )
        if moves:
            assert not tracker.estopped and tracker.link == "ok", (command, tracker)
            assert tracker.powered is not False, (command, tracker)
        if tracker.estopped and tracker.config.stop_action == "hold":
            falls = command in (p.SetAllTorque(0), p.SetPower(False)) or (
                isinstance(command, p.SetJointTorque) and not command.enable
            )
            assert not falls, (command, tracker)
        if tracker.estopped:
            turns_on = isinstance(command, p.SetPower) and command.on
            enables = isinstance(command, (p.SetAllTorque, p.SetJointTorque)) and (
                command.enable if isinstance(command, p.SetJointTorque) else command.mode > 0
            )
            assert not (turns_on or enables), (command, tracker)
    for joint, angle in result.targets_deg.items():
        low, high = JOINT_RANGE_DEG[joint]
        assert low <= angle <= high, result


def seeds() -> list[bytes]:
    """The keyspace seeds' commands (``fuzz.keyspace``), each behind a few tracker states."""
    from fuzz.keyspace import seeds as keyspace_seeds

    commands = [s for s in keyspace_seeds() if s.startswith(b'{"op"') or b'"op"' in s[:40]]
    home = bytes([128, 120, 145, 128, 153, 128, 132])  # about HOME of tests/test_agent_logic
    states = (0x00, 0x01, 0x02, 0x04, 0x09, 0x11, 0x40)
    return [bytes([state]) + home + command for state in states for command in commands]


if __name__ == "__main__":
    main(check)
