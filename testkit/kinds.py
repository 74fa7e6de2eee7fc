"""Every robot kind the agent core serves, as the safety tests see it: which unit, its keys,
a command that moves it, and how to read its latch from the key space. One table, so a safety
test runs once per kind, parametrized, never copied."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec

from fleet.client import FleetClient
from fleet.devices.base import DeviceReply, Release
from fleet.dex1.messages import GripperMove
from fleet.g1.messages import SetVelocity
from fleet.wire import keys, payloads
from fleet.wire import messages as m
from testkit.collect import Collector
from testkit.harness import FleetHarness, wait_until

G1_LOWSTATE_SLOW = "sim_lowstate_hz = 20.0\n"
"""A simulated G1's lowstate at 20 Hz, not its 100 Hz (~1 ms of Python a sample in the
simulator, ~0.5 ms in the agent), for a test that reads no lowstate rate: the agent needs one
within its 0.5 s ``link_stale_s``."""

DEVICES = (
    '[grippers.gl]\nfamily = "go"\nmount = "a1"\nsim_rate_hz = 100.0\n\n'
    f'[g1.h1]\nstop_action = "stop_move"\nsim_settle_s = 0.1\n{G1_LOWSTATE_SLOW}'
)
"""The inventory lines of the devices beside arm a1 (the harness writes the arm). The
simulators run slower than the robots (a gripper's 500 Hz state at 100 Hz, a G1's 100 Hz
lowstate at 20 Hz, as the network lab's): these tests are about safety, not rates
(tests/e2e/test_dex1_rate.py is), and at the robots' rates an idle simulator and agent of
these three took 35 % of a core, at these 16 %."""


@contextlib.contextmanager
def devices_fleet(tmp_path: Path) -> Iterator[FleetHarness]:
    """Router, ``fleet sim`` (a1 and the ``DEVICES``: gl, h1) and one agent serving them all."""
    with FleetHarness(tmp_path, arms=1, extra=DEVICES) as harness:
        harness.start_router(wait=False)  # side by side (FleetHarness.start_fleet)
        harness.start_sim()
        harness.start("agent", ["-m", "edge_agent", "--interface", "lo"])
        harness.wait_router()
        yield harness


def wait_kinds_online(harness: FleetHarness, timeout_s: float = 30.0) -> None:
    """Wait until every kind's unit reports a fresh link (else fail with the harness's
    diagnosis)."""
    client = harness.client()
    for kind in KINDS:
        watch = LatchWatch(client, kind)
        try:
            wait_until(watch.link_ok, timeout_s)
        except AssertionError:
            raise AssertionError(harness.diagnose(client)) from None


@dataclass(frozen=True)
class Kind:
    """One kind as the tests drive it: its unit id and a command that moves it."""

    name: str
    unit: str
    moves: Callable[[], Any]

    @property
    def is_arm(self) -> bool:
        return self.name == "arm"

    def label(self, client: FleetClient) -> str:
        """How ``FleetClient.estop`` and ``reset_and_report`` name the unit in their results:
        an arm by its id, a device as ``<kind>/<id>``."""
        if self.is_arm:
            return self.unit
        return next(label for label, d in client.device_labels().items() if d == self.unit)


KINDS = (
    Kind("arm", "a1", lambda: m.MoveJoint(joint=0, angle_deg=4.0)),
    Kind("gripper", "gl", lambda: GripperMove(open_pct=40.0)),
    Kind("g1", "h1", lambda: SetVelocity(vx=0.1, duration_s=0.5)),
)
KIND_IDS = [k.name for k in KINDS]


@dataclass(frozen=True)
class Outcome:
    """A command's reply reduced to what every kind answers: ok, and the error code."""

    ok: bool
    code: int | None
    message: str


def send(client: FleetClient, kind: Kind, command: Any) -> Outcome:
    """Send ``command`` (a Struct of the kind's, or raw JSON bytes) to the kind's unit."""
    if kind.is_arm:
        if isinstance(command, bytes):
            command = payloads.COMMAND.decode(command)
        if isinstance(command, Release):
            command = m.Release(owner=command.owner)
        reply: m.CommandReply | DeviceReply = client.command(kind.unit, command)
    else:
        reply = client.device_command(kind.unit, command)
    error = reply.error
    return Outcome(reply.ok, None if error is None else error.code, error.message if error else "")


def with_envelope(command: Any, **fields: Any) -> Any:
    """``command`` with envelope fields set (owner, takeover, stamp_ns, lifetime_s)."""
    return msgspec.structs.replace(command, **fields)


def release(kind: Kind, owner: str) -> Any:
    """The kind's release of ``owner``'s lease."""
    return m.Release(owner=owner) if kind.is_arm else Release(owner=owner)


class LatchWatch:
    """The unit's latch as its agent publishes it (arm status, device state), newest first."""

    def __init__(self, client: FleetClient, kind: Kind) -> None:
        self.kind = kind
        if kind.is_arm:
            decode: Callable[[bytes], Any] = payloads.STATUS.decode
        else:
            from fleet.devices import kind_of

            decode = kind_of(client.inventory.device(kind.unit)).payloads[keys.STATE].decode
        self._states = Collector(client.session, client.unit_key(kind.unit, _state(kind)), decode)

    def latest(self) -> Any:
        return self._states.latest()

    def estopped(self) -> bool | None:
        """The newest report's latch (None before one arrived)."""
        state = self._states.latest()
        return None if state is None else bool(state.estopped)

    def reason(self) -> str:
        state = self._states.latest()
        return "" if state is None else str(state.stop_reason or "")

    def link_ok(self) -> bool:
        state = self._states.latest()
        return state is not None and state.link == "ok"


def _state(kind: Kind) -> str:
    return keys.STATUS if kind.is_arm else keys.STATE
