"""A 500 Hz Dex1-1 state stream relayed for 10 s: the Zenoh rate equals the configured one
(newest wins), every DDS sample is taken (the DDS rate stays 500 Hz at the agent), and nothing
queues: the relayed state's age does not grow from the first second to the last."""

from __future__ import annotations

import time

import pytest

from fleet.dex1.kind import KIND
from fleet.dex1.messages import GripperState
from fleet.wire import keys
from testkit.collect import Collector
from testkit.harness import FleetHarness, wait_until
from testkit.load import xfail_if_overloaded

RELAY_HZ = 50.0
DDS_FLOOR_HZ = 0.95 * 500.0
"""The simulator writes 500 a second; the agent must take at least this many."""


@pytest.mark.timing
def test_500_hz_state_relayed_at_the_configured_rate_without_queueing(tmp_path) -> None:  # type: ignore[no-untyped-def]
    extra = f"[grippers.gl]\nsim_rate_hz = 500.0\nrelay_hz = {RELAY_HZ}\n"
    with FleetHarness(tmp_path, arms=1, extra=extra) as fleet:
        fleet.start_router()
        fleet.start_sim()
        fleet.start("devices", ["-m", "edge_agent", "--device", "gl"])
        client = fleet.client()
        key = keys.KeySpace(fleet.inventory.fleet).device("gripper", "gl", keys.STATE)
        states: Collector[GripperState] = Collector(
            client.session, key, KIND.payloads[keys.STATE].decode
        )
        try:
            wait_until(lambda: (s := states.latest()) is not None and s.dds_rate_hz > 400, 30.0)
            start = time.monotonic()
            wait_until(lambda: time.monotonic() - start >= 10.0, 11.0, interval_s=0.5)
            window = [(t, s) for t, s in states.timed if start <= t < start + 10.0]
            # The rate by the agent's own stamps (this client's arrival times bunch on a loaded
            # host): never above the configured rate; a starved agent skips a tick, not more.
            first_ns = window[0][1].stamp_ns
            rate = sum(first_ns <= s.stamp_ns < first_ns + 9_000_000_000 for _t, s in window) / 9.0
            first, last = window[0][1], window[-1][1]
            dds_rate = (last.dds_samples - first.dds_samples) / 10.0
            first_ages = [s.stamp_ns for _t, s in window[:50]]
            print(f"zenoh rate {rate:.1f} Hz, dds rate {dds_rate:.1f} Hz")
            assert 0.9 * RELAY_HZ <= rate <= 1.04 * RELAY_HZ, rate
            assert last.bad_samples == 0
            # No queue: consecutive relayed states are one relay period apart in their own
            # stamps at the end as at the start (a queue would bunch them and age them).
            gaps = [(b - a) / 1e6 for a, b in zip(first_ages, first_ages[1:])]
            last_stamps = [s.stamp_ns for _t, s in window[-50:]]
            last_gaps = [(b - a) / 1e6 for a, b in zip(last_stamps, last_stamps[1:])]
            mean = sum(gaps) / len(gaps)
            last_mean = sum(last_gaps) / len(last_gaps)
            period_ms = 1000 / RELAY_HZ  # a starved agent's skipped tick lengthens a gap
            assert abs(last_mean - mean) < 0.1 * period_ms + 2.0, (mean, last_mean)
            assert period_ms - 2.0 < mean < 1.1 * period_ms + 2.0, mean
            # The state's DDS sample count advances at the DDS rate between puts: the relay
            # always carries the newest sample, never an old one from a backlog.
            steps = [b.dds_samples - a.dds_samples for (_t, a), (_u, b) in zip(window, window[1:])]
            per_put = sum(steps) / len(steps)
            # Both depend on the simulator writing 500 a second: a starved one wrote 472 at
            # load 8 (three workers), which measures the scheduler, not the agent's intake.
            missed = [f"DDS rate {dds_rate:.0f} Hz"] if dds_rate < DDS_FLOOR_HZ else []
            missed += (
                [f"{per_put:.1f} samples per put"] if per_put < DDS_FLOOR_HZ / RELAY_HZ else []
            )
            xfail_if_overloaded(missed)
            assert dds_rate >= DDS_FLOOR_HZ, dds_rate
            assert per_put >= DDS_FLOOR_HZ / RELAY_HZ, per_put
        finally:
            states.close()
