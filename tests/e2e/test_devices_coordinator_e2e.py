"""Devices in the coordinator, end to end: the fleet state lists every device, a fleet stop's
report carries the devices' timings, and ``fleet status --json`` gives each device's state under
``<kind>/<id>``. Real processes: a router, ``fleet sim`` (one arm, a gripper and a G1), one
devices agent, the coordinator."""

from __future__ import annotations

import json
import threading

import pytest

from fleet.wire import messages as m
from fleet.wire import payloads
from testkit.harness import FleetHarness, wait_until
from tests.e2e.test_coordinator import _state

EXTRA = '[grippers.gl]\nmount = "a1"\n\n[g1.h1]\n'


def test_devices_in_fleet_state_stop_report_and_status_json(
    tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:  # type: ignore[no-untyped-def]
    from fleet.cli.main import main

    with FleetHarness(tmp_path, arms=1, extra=EXTRA) as fleet:
        fleet.start_router()
        fleet.start_sim()
        fleet.start_agent("a1", name="agent-a1")
        fleet.start("devices", ["-m", "edge_agent", "--device", "gl", "--device", "h1"])
        fleet.start_coordinator()
        client = fleet.client()

        def devices_online() -> bool:
            state = _state(client)
            return state is not None and all(
                d.online and d.link == "ok" for d in state.devices.values()
            )

        wait_until(devices_online, 40.0)
        state = _state(client)
        assert state is not None and set(state.devices) == {"gl", "h1"}
        assert state.devices["gl"].kind == "gripper" and state.devices["h1"].kind == "g1"
        assert "walk" in (state.devices["h1"].summary or ""), state.devices["h1"]
        reports: list[m.StopReport] = []
        lock = threading.Lock()

        def on_report(sample) -> None:  # type: ignore[no-untyped-def]
            with lock:
                reports.append(payloads.STOP_REPORT.decode(sample.payload.to_bytes()))

        sub = client.session.declare_subscriber(client.keys.stop_report, on_report)
        try:
            acks = client.estop(timeout_s=8.0)
            assert {"a1", "gripper/gl", "g1/h1"} <= set(acks), acks

            def reported() -> bool:
                with lock:
                    return any({"a1", "gl", "h1"} <= set(r.arms) for r in reports)

            wait_until(reported, 5.0)
            wait_until(lambda: (s := _state(client)) is not None and s.devices["gl"].estopped, 5.0)
        finally:
            sub.undeclare()
        capsys.readouterr()
        main(["status", "--json", "--inventory", str(fleet.inventory_path)])
        out = json.loads(capsys.readouterr().out)
        assert "a1" in out and out["gripper/gl"]["kind"] == "gripper"
        assert out["gripper/gl"]["state"]["estopped"] is True
        assert out["g1/h1"]["state"]["fsm_name"], out["g1/h1"]
