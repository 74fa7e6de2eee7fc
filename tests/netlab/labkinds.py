"""The robot kinds as the lab's fault rows see them (the lab's side of ``testkit.kinds``): which
units of a lab fleet are of a kind, how a stop acknowledgment names them, how a row moves a
device, and how a unit's pose and latch are read from what the client recorded. A row
parametrized over ``LAB_KINDS`` runs its one body for every kind.

What "still" means differs by kind and is the agent's own test, read from the unit's samples:
an arm's seven angles (within ``STILL_DEG``), a gripper's finger position ``q_rad`` (the
agent's ``STILL_RAD_S`` over a sample period is under 1 mrad), a G1's ``fsm_mode`` (static).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any, TypeVar

from fleet.dex1.relay import STILL_RAD_S
from fleet.g1 import loco
from testkit.harness import wait_until
from testkit.kinds import KIND_IDS
from tests.netlab.checks import STILL_DEG, joints_of
from tests.netlab.fleetlab import LabFleet, RemoteClient

T = TypeVar("T")
Rows = list[tuple[int, int, list[float]]]
"""(arrival ns, stamp ns, pose) of one unit, in stamp order."""

G1_VELOCITY = {"op": "set_velocity", "vx": 0.3, "duration_s": 3.0}
"""A G1 walking for 3 s (dynamic until 3 s + its settling after the command)."""
MOVING_WITHIN_S = 5.0
"""A device's state shows the motion its command started at its next state sample (a gripper
50 per second, a G1 on the FSM change): 5 s bounds that on a loaded host and a lossy link."""
MOVE_TRIES = 3
"""Commands per device before ``move_devices`` gives up (see there)."""


@dataclass(frozen=True)
class LabKind:
    """One kind of robot in the lab.

    ``key``: its word in the key space (``arm``, ``gripper``, ``g1``); ``still_tol``: how far
    apart (in the pose's unit) the samples of a still unit may be; ``moved_min``: how far its
    pose must change after a fault for the unit to count as moving at the fault."""

    name: str
    key: str
    still_tol: float
    moved_min: float

    @property
    def is_arm(self) -> bool:
        return self.name == "arm"

    def units(self, fleet: LabFleet) -> list[str]:
        """The ids of the lab's units of this kind."""
        if self.is_arm:
            return list(fleet.arms)
        return [d for d, dev in fleet.devices.items() if _key_of(dev.section) == self.key]

    def label(self, unit: str) -> str:
        """How ``FleetClient.estop`` names the unit in its acks."""
        return unit if self.is_arm else f"{self.key}/{unit}"

    def poses(self, samples: list[Any], unit: str) -> Rows:
        """The unit's poses from recorded samples (see the module docstring), in stamp order."""
        if self.is_arm:
            return joints_of(samples, unit)
        field = "q_rad" if self.name == "gripper" else "fsm_mode"
        rows = [
            (t, value["stamp_ns"], [float(value[field])])
            for t, u, channel, value in samples
            if u == unit and channel == "state"
        ]
        return sorted(rows, key=lambda row: row[1])

    def latches(self, samples: list[Any], unit: str) -> list[tuple[int, dict[str, Any]]]:
        """(arrival ns, status or state) of the unit, in arrival order: each carries
        ``stamp_ns``, ``estopped`` and ``stop_reason``."""
        channel = "status" if self.is_arm else "state"
        return [(t, v) for t, u, c, v in samples if u == unit and c == channel]

    def moving(self, state: dict[str, Any] | None) -> bool:
        """A device's state shows it moving (a gripper's fingers faster than the agent's
        still speed, a G1 stepping)."""
        if state is None:
            return False
        if self.name == "gripper":
            return abs(state["dq_rad_s"]) > STILL_RAD_S
        return bool(state["fsm_mode"] == loco.DYNAMIC)

    def long_move(self, state: dict[str, Any]) -> dict[str, Any]:
        """A device command that keeps it moving for more than a second from ``state``: a
        gripper to its far end (a full stroke is 3.1 s at the lab's 2 rad/s), a G1 walking."""
        if self.name == "gripper":
            return {"op": "move", "open_pct": 0.0 if state["opening_pct"] > 50 else 100.0}
        return dict(G1_VELOCITY)


def move_devices(
    fleet: LabFleet,
    client: RemoteClient,
    kind: LabKind,
    principal: str | None = None,
    owner: str | None = None,
    timings: dict[str, dict[str, float]] | None = None,
) -> bool:
    """Send each of the lab's devices of ``kind`` its ``long_move`` (as ``principal``, owned by
    ``owner``) and wait until its state shows it moving; True if every command was accepted.

    Up to ``MOVE_TRIES`` commands per device, each from its newest state: after a level of
    heavy loss the client's copy of a state can be old (a gripper already at the end the
    command chose does not move), or a command can meet a session still reconnecting. Setting
    the units moving is this helper's job, not what a row measures; the tries are printed.
    ``timings`` (if given) gets each unit's last command: how long its reply took and when its
    state showed it moving, in seconds from that command, and ``moving_ns`` (the clock's)."""
    ok = True
    for unit in kind.units(fleet):
        tries: list[dict[str, Any]] = []

        def moving(unit: str = unit) -> bool:
            return kind.moving(client.call("device_state", unit=unit)["state"])

        while len(tries) < MOVE_TRIES:
            state = client.call("device_state", unit=unit)["state"]
            command = kind.long_move(state) | ({"owner": owner} if owner else {})
            sent = time.monotonic()
            moved = client.call("device_command", unit=unit, command=command, principal=principal)
            replied = time.monotonic()
            tries.append({"state": state, "command": command, "reply": moved["reply"]})
            try:
                wait_until(moving, MOVING_WITHIN_S)
                if timings is not None:
                    timings[unit] = {
                        "reply_s": round(replied - sent, 3),
                        "moving_s": round(time.monotonic() - sent, 3),
                        "moving_ns": time.time_ns(),
                    }
                break
            except AssertionError:
                continue
        else:
            raise AssertionError(f"{unit} never moved: {tries}")
        if len(tries) > 1:
            print(f"\n{unit} moved at try {len(tries)}: {tries[:-1]}")
        ok = ok and bool(tries[-1]["reply"]["ok"])
    return ok


class SharedRuns:
    """One run of a fault with every kind's units in it, kept for the kinds' tests of that
    fault: the first kind's test makes it, the others read it. Each kind keeps its own test,
    verdict and record; the fault is made once, not once per kind (a fleet stop, a lost
    coordinator or a router restart meets every kind at once in a real fleet too)."""

    def __init__(self) -> None:
        self._runs: dict[Hashable, Any] = {}

    def get(self, key: Hashable, run: Callable[[], T]) -> T:
        """``run()``'s result, made on the first call for ``key``. A run that raised is not
        made again: the later kinds fail, pointing at the first kind's test."""
        if key not in self._runs:
            self._runs[key] = None  # stays None if run() raises
            self._runs[key] = run()
        value = self._runs[key]
        if value is None:
            raise AssertionError(f"the shared run {key!r} failed: see the first kind's test")
        return value  # type: ignore[no-any-return]


def every_unit(fleet: LabFleet) -> dict[str, LabKind]:
    """Every unit of the lab with its kind."""
    return {unit: kind for kind in LAB_KINDS for unit in kind.units(fleet)}


def _key_of(section: str) -> str:
    return {"grippers": "gripper", "g1": "g1"}[section]


LAB_KINDS = (
    LabKind("arm", "arm", STILL_DEG, 2.0),
    # 0.01 rad: the hold targets the position the agent last read (up to one 20 ms poll old,
    # 0.04 rad behind at 2 rad/s), and the fingers settle back onto it within 20 ms.
    LabKind("gripper", "gripper", 0.01, 0.1),
    # fsm_mode 1 (dynamic) -> 0 (static): the change is the motion.
    LabKind("g1", "g1", 0.5, 1.0),
)
assert [k.name for k in LAB_KINDS] == KIND_IDS, "one kind table: testkit.kinds names them"
LAB_KIND_IDS = KIND_IDS
