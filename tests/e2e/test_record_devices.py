"""``fleet record`` records the devices beside the arms (issue 14): a gripper's state and a
G1's state are in the file with their own schemas; ``fleet replay`` read-only re-publishes every
kind's state (issue 21), and ``fleet viewer --replay`` shows the devices too. Real
processes: a router, ``fleet sim`` (one arm, a gripper, a G1), the arm's agent,
one devices agent, ``fleet record``."""

from __future__ import annotations

import threading
from pathlib import Path

import zenoh
from mcap.reader import make_reader

from fleet.dex1.kind import KIND as GRIPPER
from fleet.g1.kind import KIND as G1
from fleet.record.reader import read_recording
from fleet.record.replay import replay_read_only
from fleet.wire import keys
from testkit.harness import FleetHarness, wait_until
from tests.e2e.test_record_e2e import FLEET_CLI, _exited

EXTRA = '[grippers.gl]\nmount = "a1"\n\n[g1.h1]\n'


def test_devices_recorded_and_replayed(tmp_path: Path) -> None:
    path = tmp_path / "mixed.mcap"
    with FleetHarness(tmp_path, arms=1, extra=EXTRA) as fleet:
        fleet.start_router()
        fleet.start_sim()
        fleet.start_agent("a1", name="agent-a1")
        fleet.start("devices", ["-m", "edge_agent", "--device", "gl", "--device", "h1"])
        client = fleet.client()
        wait_until(lambda: all(s is not None for s in client.device_snapshot().values()), 40.0)
        wait_until(lambda: fleet.all_links_ok(client), 30.0)
        fleet.start("record", [*FLEET_CLI, "record", "-o", str(path), "--for-s", "3"])
        assert _exited(fleet, "record", 30.0) == 0, fleet.log("record")
        recording = read_recording(path)
        space = keys.KeySpace(fleet.inventory.fleet)
        grip_key = space.device("gripper", "gl", keys.STATE)
        g1_key = space.device("g1", "h1", keys.STATE)
        by_key: dict[str, list[bytes]] = {}
        for message in recording.messages:
            by_key.setdefault(message.key, []).append(message.data)
        assert len(by_key.get(grip_key, [])) >= 50, sorted(by_key)  # 50 Hz for 3 s
        assert len(by_key.get(g1_key, [])) >= 10, sorted(by_key)
        assert GRIPPER.payloads[keys.STATE].decode(by_key[grip_key][-1]).mount == "a1"
        assert G1.payloads[keys.STATE].decode(by_key[g1_key][-1]).fsm_name == "walk"
        assert space.arm("a1", keys.JOINTS) in by_key
        with open(path, "rb") as stream:
            summary = make_reader(stream).get_summary()
        assert summary is not None
        schemas = {
            channel.topic: summary.schemas[channel.schema_id].name
            for channel in summary.channels.values()
        }
        assert schemas[grip_key] == "GripperState" and schemas[g1_key] == "G1State"
        # Read-only replay into another fleet: the arm's state only, device keys ignored.
        heard: list[str] = []
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                heard.append(str(sample.key_expr))

        sub = client.session.declare_subscriber("fleet/replayed/**", on_sample)
        try:
            published = replay_read_only(
                client.session, list(recording.messages), "replayed", threading.Event(), 20.0
            )
        finally:
            sub.undeclare()
        assert published > 0
        with lock:  # every kind's state is replayed (issue 21), never a command or a stop
            replayed = set(heard)
        assert {"fleet/replayed/gripper/gl/state", "fleet/replayed/g1/h1/state"} <= replayed
        assert "fleet/replayed/arm/a1/joints" in replayed
        assert not any(k.endswith(("/estop", "/reset")) or "/cmd/" in k for k in replayed)
    from viewer.replay import replay_source

    source = replay_source(recording)  # what `fleet viewer --replay` shows: every kind
    shown = {r.key for r in source.messages}
    assert {grip_key, g1_key, space.device("g1", "h1", keys.LOWSTATE)} <= shown
    assert set(source.layout.devices) == {"gl", "h1"}
