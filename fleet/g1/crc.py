"""Unitree's CRC of ``unitree_hg`` ``LowCmd_`` / ``LowState_``. Pure.

As unitree_sdk2py's ``utils/crc.py`` computes it: the message packed little-endian with C
alignment (``LowCmd_`` 1004 bytes, ``LowState_`` 2092), read as 32-bit words without the last
(the crc itself), fed MSB first through CRC-32 (polynomial 0x04C11DB7, initial 0xFFFFFFFF, no
reflection, no final xor): CRC-32/MPEG-2 over each word's big-endian bytes. Computed with
zlib's reflected CRC-32 on the bit-reversed bytes (the same register, mirrored): ~40 us a
``LowState_`` instead of ~230 us for a table loop in Python, so the agent checks every one of
the robot's 500 samples a second (the SDK calls a shared library); ``tests/unit/test_g1_arms.py``
checks it against the SDK's.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any

LOW_CMD_FORMAT = struct.Struct("<2B2x" + "B3x5fI" * 35 + "5I")
LOW_STATE_FORMAT = struct.Struct("<2I2B2xI" + "13fh2x" + "B3x4f2hf7I" * 35 + "40B5I")
_BITS_REVERSED = bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))


def crc32_words(packed: bytes) -> int:
    """Unitree's CRC of ``packed`` (all words but the last: the crc field). An unreflected
    CRC (init all ones) equals the mirror of the reflected one over bit-mirrored bytes; zlib's
    final xor is undone."""
    words = len(packed) // 4 - 1
    swapped = struct.pack(f">{words}I", *struct.unpack_from(f"<{words}I", packed))
    mirrored = zlib.crc32(swapped.translate(_BITS_REVERSED)) ^ 0xFFFFFFFF
    return int(f"{mirrored:032b}"[::-1], 2)


def low_cmd_crc(cmd: Any) -> int:
    """The CRC of a ``LowCmd_`` (ours or the SDK's: same fields)."""
    values: list[Any] = [cmd.mode_pr, cmd.mode_machine]
    for motor in cmd.motor_cmd:
        values += (motor.mode, motor.q, motor.dq, motor.tau, motor.kp, motor.kd, motor.reserve)
    values += [*cmd.reserve, cmd.crc]
    return crc32_words(LOW_CMD_FORMAT.pack(*values))


def low_state_crc(state: Any) -> int:
    """The CRC of a ``LowState_`` (ours or the SDK's)."""
    imu = state.imu_state
    values: list[Any] = [*state.version, state.mode_pr, state.mode_machine, state.tick]
    values += [*imu.quaternion, *imu.gyroscope, *imu.accelerometer, *imu.rpy, imu.temperature]
    for s in state.motor_state:
        values += (s.mode, s.q, s.dq, s.ddq, s.tau_est, *s.temperature, s.vol, *s.sensor)
        values += (s.motorstate, *s.reserve)
    values += [*state.wireless_remote, *state.reserve, state.crc]
    return crc32_words(LOW_STATE_FORMAT.pack(*values))
