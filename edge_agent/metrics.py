"""The agent's Prometheus collectors: read at scrape time from the counters the agent keeps for
its diag anyway (the relay thread does nothing more for metrics); command latencies from the
agent's bounded ``reply_latencies_s`` deque."""

from __future__ import annotations

import time
from typing import Any

from fleet.metrics import FunctionCollector, LatencySink, counter, gauge
from fleet.wire.keys import ARM

# (counter or gauge, name, help, value from (diag, status, commands in flight)) per arm
PER_ARM: tuple[tuple[Any, str, str, Any], ...] = (
    (counter, "d1_agent_relayed", "angle and status reports relayed", lambda d, s, f: d.relayed),
    (counter, "d1_agent_malformed", "feedback that did not decode", lambda d, s, f: d.malformed),
    (counter, "d1_agent_refused", "commands refused by the agent", lambda d, s, f: d.rejected),
    (counter, "d1_agent_commands", "commands written to the arm", lambda d, s, f: d.commands),
    (counter, "d1_agent_ack_timeouts", "acks that did not arrive", lambda d, s, f: d.ack_timeouts),
    (counter, "d1_agent_foreign", "feedback not from the arm", lambda d, s, f: d.foreign_feedback),
    (counter, "d1_agent_implausible", "impossible jumps", lambda d, s, f: d.implausible_feedback),
    (gauge, "d1_agent_feedback_rate_hz", "angle reports/s", lambda d, s, f: d.feedback_rate_hz),
    (gauge, "d1_agent_feedback_age_seconds", "feedback age", lambda d, s, f: d.last_feedback_age_s),
    (gauge, "d1_agent_link_ok", "1 when the link is ok", lambda d, s, f: d.link == "ok"),
    (gauge, "d1_agent_estopped", "1 while a stop is latched", lambda d, s, f: s.estopped),
    (gauge, "d1_agent_lease_held", "1 while a lease is held", lambda d, s, f: s.owner is not None),
    (gauge, "d1_agent_lease_left_seconds", "lease seconds left", lambda d, s, f: s.lease_left_s),
    (gauge, "d1_agent_in_flight", "commands awaiting acks or targets", lambda d, s, f: f),
)


# The same for every device (gripper, G1), from its diag and the core's safety state.
PATHS = (("reliable", False), ("datagram", True))
"""A stop's or heartbeat's two paths (``fleet/wire/stoppath.py``): label, and the counters'
key."""

PER_DEVICE: tuple[tuple[Any, str, str, Any], ...] = (
    (counter, "d1_agent_device_relayed", "state samples relayed", lambda d, s: d.relayed),
    (counter, "d1_agent_device_malformed", "state that did not decode", lambda d, s: d.malformed),
    (counter, "d1_agent_device_refused", "commands refused", lambda d, s: d.rejected),
    (counter, "d1_agent_device_commands", "commands written", lambda d, s: d.commands),
    (counter, "d1_agent_device_timeouts", "answers that did not come", lambda d, s: d.ack_timeouts),
    (counter, "d1_agent_device_foreign", "state not from it", lambda d, s: d.foreign_feedback),
    (
        counter,
        "d1_agent_device_implausible",
        "impossible jumps",
        lambda d, s: d.implausible_feedback,
    ),
    (gauge, "d1_agent_device_rate_hz", "DDS state samples/s", lambda d, s: d.feedback_rate_hz),
    (gauge, "d1_agent_device_link_ok", "1 when the link is ok", lambda d, s: d.link == "ok"),
    (gauge, "d1_agent_device_estopped", "1 while a stop is latched", lambda d, s: s.latched),
    (gauge, "d1_agent_device_lease_held", "1 while leased", lambda d, s: s.lease is not None),
)


def agent_collectors(agent: Any) -> list[Any]:
    """The collectors of an ``EdgeAgent`` (registered by ``--metrics-port``; typed Any: nothing
    imports edge_agent.agent but __main__). Reads its ``lock``, ``slots``, ``counters``,
    inboxes, ``reply_latencies_s`` and its relay's datagram session."""
    latency = LatencySink(pending=agent.reply_latencies_s)

    def collect() -> list[Any]:
        now, stamp_ns = time.monotonic(), time.time_ns()
        with agent.lock:  # copies only: no I/O under the lock
            rows = {
                arm: (
                    slot.tracker.diag(now, stamp_ns),
                    slot.tracker.status(now, stamp_ns),
                    len(slot.in_flight),
                )
                for arm, slot in agent.sides[ARM].units.items()
            }
            counters = agent.counters
            own = {
                "d1_agent_bad_payloads": counters.bad_payloads,
                "d1_agent_busy": counters.busy,
                "d1_agent_bad_keys": counters.bad_keys,
                "d1_agent_latch_failures": agent.latches.failures,
                "d1_agent_dropped_events": counters.dropped_events,
            }
            copies = {
                name: [([path], per_path[datagram]) for path, datagram in PATHS]
                for name, per_path in (
                    ("d1_agent_stop_copies", counters.stop_copies),
                    ("d1_agent_heartbeat_copies", counters.beat_copies),
                )
            }
        metrics = [
            kind(name, text, ["arm"], [([arm], get(*row)) for arm, row in rows.items()])
            for kind, name, text, get in PER_ARM
        ]
        devices = {
            device: (slot.kind, agent.devices.diag(device, now, stamp_ns), slot.safety)
            for device, slot in agent.devices.slots.items()
        }
        metrics += [
            kind(
                name,
                text,
                ["device", "kind"],
                [([d, k], get(diag, safety)) for d, (k, diag, safety) in devices.items()],
            )
            for kind, name, text, get in PER_DEVICE
        ]
        metrics += [
            counter(name, "the agent's own count", [], [([], v)]) for name, v in own.items()
        ]
        metrics += [
            counter(name, "copies received per path, before de-duplication", ["path"], rows)
            for name, rows in copies.items()
        ]
        metrics.append(
            counter(
                "d1_agent_datagram_replaced",
                "times the datagram session was replaced (link re-made, or deaf)",
                [],
                [([], agent.relay.datagram.replaced)],
            )
        )
        depths = [
            (["safety"], agent.safety_inbox.depth()),
            (["commands"], agent.command_inbox.depth()),
        ]
        metrics.append(
            gauge("d1_agent_queue_depth", "items in the agent's inboxes", ["queue"], depths)
        )
        metrics.append(
            latency.family("d1_agent_command_latency_seconds", "a command's arrival to its reply")
        )
        return metrics

    return [FunctionCollector(collect)]
