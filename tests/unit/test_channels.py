"""The channel table (issue 21): every kind's payloads are in it, each row is found from the
keys it travels on through the one key parser, and ``fleet schema`` / ``fleet echo`` see them."""

from __future__ import annotations

import json

import msgspec
import pytest

from fleet import tap
from fleet.cli.status import run_schema
from fleet.devices import kinds
from fleet.dex1.messages import GripperHold
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.samples import GRIP_STATE as STATE

KS = keys.KeySpace("lab")
NO_PAYLOAD = {keys.AGENT, keys.RAW_FEEDBACK, keys.SIM_FAULT}
"""Channels that carry no decodable payload: liveliness tokens, the arm's own text, and the
simulator's fault requests (their kind lives in fleet/sim/faults.py)."""


def _concrete(place: payloads.Place) -> str:
    kind, channel = place
    if kind == keys.ARM:
        return KS.command("a1", "ann") if channel == keys.CMD else KS.arm("a1", channel)
    if kind in keys.DEVICE_KINDS:
        if channel == keys.CMD:
            return KS.device_command(kind, "d1", "ann")
        return KS.device(kind, "d1", channel)
    return {
        keys.HEARTBEAT: KS.heartbeat_of("ann"),
        keys.COORDINATOR_CMD: KS.coordinator_command("ann"),
        keys.INFO: KS.info("agent", "host"),
        keys.CHOREO: KS.choreo_of("ann"),
    }.get(channel, f"{KS.prefix}/{channel}")


@pytest.mark.parametrize("row", payloads.CHANNELS.values(), ids=lambda row: row.kind)
def test_each_row_is_found_from_its_keys(row: payloads.Channel) -> None:
    assert row.places, row
    for place in row.places:
        parsed = KS.parse_key(_concrete(place))
        assert payloads.channel_of(parsed, reply=row.reply) is row


@pytest.mark.parametrize(
    ("kind", "channels"),
    [(keys.ARM, keys.ARM_CHANNELS)] + [(k, keys.DEVICE_CHANNELS) for k in keys.DEVICE_KINDS],
)
def test_every_channel_with_a_payload_has_a_row(kind: str, channels: tuple[str, ...]) -> None:
    for channel in channels:
        key = KS.parse_key(_concrete((kind, channel)))
        row = payloads.channel_of(key)
        own = (kind == "g1" and channel == keys.CONTACT) or (
            kind == "gripper" and channel == keys.LOWSTATE
        )
        if channel in NO_PAYLOAD or own:
            assert row is None, (kind, channel)
        else:
            assert row is not None, (kind, channel)
    if kind != keys.ARM:
        assert payloads.channel_of(KS.parse_key(_concrete((kind, keys.CMD))), reply=True)


def test_the_device_kinds_decode_with_the_table() -> None:
    for key, kind in kinds().items():
        assert kind.payloads == payloads.device_payloads(key)
        assert kind.payloads[keys.STATE] is payloads.CHANNELS[f"{key}/state"].payload
    assert payloads.CHANNELS["gripper/diag"].payload is payloads.DIAG
    assert payloads.CHANNELS["g1/cmd reply"].payload.struct is m.DeviceReply


def test_fleet_schema_lists_every_kind(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_schema(None) == 0  # type: ignore[arg-type]
    schema = json.loads(capsys.readouterr().out)
    assert set(schema["keys"]) == {row.key for row in payloads.CHANNELS.values()}
    for key in ("gripper/<id>/state", "g1/<id>/cmd/<principal> (request)", "g1/<id>/diag"):
        assert key in schema["keys"]
    assert {"GripperState", "G1State", "GripperMove", "SetVelocity", "DeviceReply"} <= set(
        schema["$defs"]
    )


def test_echo_decodes_device_keys() -> None:
    assert tap.kind_of(KS, "fleet/lab/gripper/gl/state") == "gripper/state"
    assert tap.kind_of(KS, "fleet/lab/g1/h1/cmd/ann") == "g1/cmd"
    assert tap.kind_of(KS, "fleet/lab/g1/h1/estop/ack") == "g1/estop/ack"
    assert tap.kind_of(KS, "fleet/lab/gripper/gl/agent") == "gripper/agent"
    assert tap.kind_of(KS, "fleet/lab/robot/r1/state") is None
    state = tap.decode_sample(KS, "fleet/lab/gripper/gl/state", msgspec.json.encode(STATE))
    assert state.error is None and state.payload["opening_pct"] == 15.9
    hold = tap.decode_sample(KS, "fleet/lab/gripper/gl/cmd/ann", m.encode(GripperHold()))
    assert hold.kind == "gripper/cmd" and hold.payload["op"] == "hold"
    assert hold.payload["owner"] is None  # the envelope every kind shares
    bad = tap.decode_sample(KS, "fleet/lab/g1/h1/state", b"{}")
    assert bad.kind == "g1/state" and bad.error is not None and "no channel" not in bad.error
