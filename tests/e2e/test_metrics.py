"""Prometheus metrics (issue 16): every long-running process serves them with --metrics-port,
on 127.0.0.1 only; a real fleet is scraped before and after a command and a stop."""

from __future__ import annotations

import collections
import socket
import urllib.request
from pathlib import Path

from prometheus_client.parser import text_string_to_metric_families

from fleet.doctor import interface_address
from fleet.metrics import LatencySink
from fleet.wire import messages as m
from testkit.harness import FleetHarness, free_port, wait_until

Samples = dict[tuple[str, tuple[tuple[str, str], ...]], float]


def scrape(port: int) -> Samples:
    """Every sample served on 127.0.0.1:port/metrics, by (name, labels)."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as reply:
        text = reply.read().decode()
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def value(samples: Samples, name: str, **labels: str) -> float | None:
    return samples.get((name, tuple(sorted(labels.items()))))


def test_latency_sink_buckets_and_outside_deque() -> None:
    pending: collections.deque[float] = collections.deque(maxlen=3)
    sink = LatencySink(buckets=(0.01, 0.1), pending=pending)
    for seconds in (0.005, 0.05, 0.5, 0.02):  # the first falls out of the 3-deep deque
        pending.append(seconds)
    buckets, total, _dropped = sink.drain()
    assert buckets == [("0.01", 0), ("0.1", 2), ("+Inf", 3)]
    assert abs(total - 0.57) < 1e-9
    pending.append(0.001)
    assert sink.drain()[0] == [("0.01", 1), ("0.1", 3), ("+Inf", 4)]  # cumulative


def test_every_process_serves_metrics_on_loopback(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=2) as harness:
        ports = {name: free_port() for name in ("router", "sim", "agent", "coordinator")}
        harness.start_router("--metrics-port", str(ports["router"]))
        harness.start("sim", ["-m", "fleet.cli.main", "sim", "--metrics-port", str(ports["sim"])])
        agent = ["-m", "edge_agent", "--arm", "a1", "--arm", "a2"]
        harness.start("agent", [*agent, "--metrics-port", str(ports["agent"])])
        coordinator = ["-m", "fleet.cli.main", "coordinator"]
        harness.start("coordinator", [*coordinator, "--metrics-port", str(ports["coordinator"])])
        client = harness.client()
        wait_until(lambda: harness.all_links_ok(client), 30.0)

        for name, port in ports.items():
            samples = wait_until(lambda port=port: _try_scrape(port), 15.0)
            role = "agent" if name == "agent" else name
            infos = [k for k in samples if k[0] == "d1_process_info"]
            assert len(infos) == 1 and ("role", role) in infos[0][1], (name, infos)
            assert value(samples, "process_cpu_seconds_total") is not None
        # Bound to 127.0.0.1 only: the host's other address refuses.
        other = interface_address("eth0")
        if other is not None:
            with socket.socket() as probe:
                assert probe.connect_ex((other, ports["agent"])) != 0

        agent_samples = wait_until(lambda: _feedback_counted(ports["agent"]), 10.0)
        assert value(agent_samples, "d1_agent_relayed_total", arm="a1") > 0  # type: ignore[operator]
        # The agent's rate is over its recent window: right after the link came up it may hold
        # a few reports close together (the simulator's jitter), so it settles first.
        wait_until(
            lambda: (
                5.0
                < (value(scrape(ports["agent"]), "d1_agent_feedback_rate_hz", arm="a2") or 0)
                < 12.0
            ),
            10.0,
        )
        assert value(agent_samples, "d1_agent_link_ok", arm="a1") == 1.0
        assert value(agent_samples, "d1_agent_queue_depth", queue="commands") == 0.0
        before = value(agent_samples, "d1_agent_command_latency_seconds_count") or 0.0

        reply = client.command("a1", m.MoveJoint(joint=0, angle_deg=5.0, owner="metrics"))
        assert reply.ok, reply.error
        after = scrape(ports["agent"])
        assert value(after, "d1_agent_command_latency_seconds_count") == before + 1
        assert value(after, "d1_agent_commands_total", arm="a1") >= 1  # type: ignore[operator]
        assert value(after, "d1_agent_lease_held", arm="a1") == 1.0
        assert value(after, "d1_agent_lease_held", arm="a2") == 0.0
        latency = value(after, "d1_agent_command_latency_seconds_sum")
        assert latency is not None and 0 < latency < 5

        refused = client.command("a1", m.MoveJoint(joint=1, angle_deg=500.0))
        assert not refused.ok
        acks = client.estop(reason="metrics test")
        assert all(ack is not None for ack in acks.values())
        stops = wait_until(lambda: _stop_counted(ports["coordinator"]), 10.0)
        assert value(stops, "d1_stop_received_latency_seconds_count") == 2.0  # one per arm
        # The fleet-wide figure: one per stop, the slowest arm's (issue 24).
        last = wait_until(lambda: _last_arm_counted(ports["coordinator"]), 10.0)
        assert value(last, "d1_stop_last_arm_received_latency_seconds_count") == 1.0
        assert value(stops, "d1_coordinator_arm_online", arm="a2") == 1.0
        assert value(scrape(ports["agent"]), "d1_agent_estopped", arm="a2") == 1.0
        # The coordinator's beats and the stop came on both paths, each counted on its own.
        after_stop = scrape(ports["agent"])
        for family in ("d1_agent_stop_copies_total", "d1_agent_heartbeat_copies_total"):
            for path in ("reliable", "datagram"):
                assert (value(after_stop, family, path=path) or 0) > 0, (family, path)
        assert value(after_stop, "d1_agent_datagram_replaced_total") == 0.0
        # The reports count up as the simulator runs (the whole test may take under 2 s).
        first = value(scrape(ports["sim"]), "d1_sim_reports_total")
        assert first is not None and first > 0
        wait_until(lambda: (value(scrape(ports["sim"]), "d1_sim_reports_total") or 0) > first, 5)
        client.reset()


def _try_scrape(port: int) -> Samples | None:
    try:
        return scrape(port)
    except OSError:
        return None


def _feedback_counted(port: int) -> Samples | None:
    samples = scrape(port)
    rates = [value(samples, "d1_agent_feedback_rate_hz", arm=arm) for arm in ("a1", "a2")]
    return samples if all(r is not None and r > 0 for r in rates) else None


def _stop_counted(port: int) -> Samples | None:
    samples = scrape(port)
    count = value(samples, "d1_stop_received_latency_seconds_count") or 0
    return samples if count >= 2 else None


def _last_arm_counted(port: int) -> Samples | None:
    samples = scrape(port)
    count = value(samples, "d1_stop_last_arm_received_latency_seconds_count") or 0
    return samples if count >= 1 else None
