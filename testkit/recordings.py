"""A small recording of the demo inventory's a1 (and, if asked, its gripper gl and G1 h1),
written with the fleet's own writer, that the viewer's replay tests (unit and browser) read."""

from __future__ import annotations

from pathlib import Path

import msgspec

from fleet.g1.messages import G1LowState
from fleet.inventory import load_inventory
from fleet.record.layout import LAYOUT_METADATA, layout_metadata, layout_of
from fleet.record.writer import RecordingWriter
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import encode
from testkit.samples import GRIP_STATE, g1_state

INVENTORY = Path(__file__).resolve().parents[1] / "inventory.toml"
SPACE = keys.KeySpace("lab")


MALFORMED_LOWSTATE_AT_S = 2.5
"""``devices=True`` writes one lowstate of 28 joints here: what a damaged file holds."""


def write_recording(path: Path, layout: bool = True, devices: bool = False) -> None:
    """a1's joint 0 going 0 -> 50 deg over 5 s at 10 Hz, its status at 4 Hz, a stop latched at
    3 s (with the request), and a contact at 4 s. With ``devices``: gl (mounted on a1) opening
    0 -> 100 % and h1's left shoulder pitch 0 -> -1 rad over the same 5 s, h1's state (FSM 500)
    latched at 3 s, and one malformed h1 lowstate (``MALFORMED_LOWSTATE_AT_S``)."""
    metadata = {LAYOUT_METADATA: layout_metadata(layout_of(load_inventory(INVENTORY)))}
    writer = RecordingWriter(path, metadata if layout else None)
    t0 = 1_700_000_000_000_000_000
    seq = 0

    def add(key: str, channel: str, payload: object, at_s: float) -> None:
        nonlocal seq
        seq += 1
        writer.add(key, channel, encode(payload), t0 + int(at_s * 1e9), seq)

    for k in range(51):
        at = k * 0.1
        angles = [k * 1.0, 0, 0, 0, 0, 0, 0]
        add(SPACE.arm("a1", keys.JOINTS), keys.JOINTS, m.Joints(t0, angles, k + 1), at)
        if k % 2 == 0:
            stopped = at >= 3.0
            status = m.ArmStatus(
                stamp_ns=t0, link="ok", estopped=stopped, stop_reason="snag" if stopped else None
            )
            add(SPACE.arm("a1", keys.STATUS), keys.STATUS, status, at)
    stop = m.StopRequest(stamp_ns=t0, source="ann", stop_id="s1", reason="snag")
    for repeat in range(5):  # repeated until acknowledged: one event
        add(SPACE.estop, keys.ESTOP, stop, 2.95 + repeat * 0.01)
    contact = m.ContactEvent(
        stamp_ns=t0, joint=2, state="confirmed", method="stall", error_deg=6.0, confidence=0.9
    )
    add(SPACE.arm("a1", keys.CONTACT), keys.CONTACT, contact, 4.0)
    add(SPACE.arm("a1", keys.RAW_COMMAND), keys.RAW_COMMAND, {"seq": 1}, 4.1)  # not shown
    if devices:
        _add_devices(writer, t0)
    writer.finish()


def _add_devices(writer: RecordingWriter, t0: int) -> None:
    """gl's and h1's samples, each with its kind's schema (as ``fleet record`` stores them)."""
    grip, state, low = (
        SPACE.device(kind, unit, channel)
        for kind, unit, channel in (
            ("gripper", "gl", keys.STATE),
            ("g1", "h1", keys.STATE),
            ("g1", "h1", keys.LOWSTATE),
        )
    )
    for k in range(51):
        at = t0 + int(k * 0.1 * 1e9)
        opening = msgspec.structs.replace(GRIP_STATE, stamp_ns=at, opening_pct=2.0 * k)
        writer.add(grip, "device", encode(opening), at, k, type(GRIP_STATE))
        q = [0.0] * 29
        q[15] = -k / 50.0
        pose = G1LowState(at, q, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], k, 0)
        writer.add(low, "device", encode(pose), at, k, G1LowState)
        fsm = msgspec.structs.replace(g1_state("sport", "sport", True), estopped=k >= 30)
        writer.add(state, "device", encode(fsm), at, k, type(fsm))
    hostile = msgspec.json.encode({**msgspec.to_builtins(pose), "q_rad": [0.0] * 28})
    at = t0 + int(MALFORMED_LOWSTATE_AT_S * 1e9) + 1
    writer.add(low, "device", hostile, at, 99, G1LowState)
