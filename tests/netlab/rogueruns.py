"""Fault matrix, row 4, what it does to each kind (``test_rogue_dds.py`` checks it): a rogue
DDS participant on a robot's own network, and what the client, the agent's ``diag``, the relayed
states and (for the arm) a spy on its command topic saw meanwhile.

``arm_run``: ``ddstool.py rogue`` on a1's feedback topic, malformed and forged D1 strings, while
a1 stands at joint 0 = 20 deg; a command and a stop of a1 during it. ``device_run``: ``ddstool.py
forge`` on a device's state topic from its own host, a forged state of its Unitree type, while
the device stands; a command that leaves it there, and a stop of it, during it.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

from fleet.d1 import protocol
from fleet.g1 import loco
from testkit.harness import wait_until
from tests.netlab.checks import commands_seen, restore
from tests.netlab.fleetlab import LabFleet
from tests.netlab.labkinds import LabKind

ARM = "a1"
ROGUE_S = 5.0
RATE_HZ = 100.0
FORGED = [-60.0, 30.0, 30.0, 0.0, 0.0, 0.0, 10.0]
FORGE_S = 4.0
FORGE_HZ = 200.0
"""A device's rogue: twice the lab gripper's own 100 Hz and the G1's sportmodestate."""
FLOOD_SEEN = 20
"""Forged samples the device's diag counts before the command and the stop (0.1 s of it)."""
STATE_TOPICS = {"gripper": "rt/dex1/left/state", "g1": loco.STATE_TOPIC}
"""The lab's devices' state topics (``gl`` is a left Dex1-1 on the default topics)."""


def _diag(client: Any, unit: str = ARM, after_ns: int = 0) -> dict[str, Any]:
    diag = client.call("diag", unit=unit, after_ns=after_ns)["diag"]
    assert diag is not None, f"no diag of {unit} from its agent"
    return diag


def move(client: Any, angle: float, wait: bool) -> dict[str, Any]:
    """Move a1's joint 0 to ``angle`` (``wait``: until reached); the agent's reply."""
    command = {"op": "move_joint", "joint": 0, "angle_deg": angle, "wait_reached": wait}
    return client.call("command", arm=ARM, command=command)["reply"]


def _alive(lab1: LabFleet) -> dict[str, int | None]:
    prefixes = ("sim-", "agent-", "router", "coordinator", "cable", "client")
    return {n: c for n, c in lab1.lab.alive().items() if n.startswith(prefixes)}


def _stop_ms(stop: dict[str, Any], ack: dict[str, Any] | None, field: str) -> float | None:
    return (ack[field] - stop["stamp_ns"]) / 1e6 if ack and ack[field] else None


def arm_run(lab1: LabFleet) -> dict[str, Any]:
    """One rogue run against a1 (standing at joint 0 = 20 deg); what was seen."""
    client = lab1.clients["client"]
    restore(lab1, client)
    assert move(client, 20.0, wait=True)["ok"]
    before_pose = client.call("snapshot", arms=[ARM])["arms"][ARM][1]["angles_deg"]
    if "spy-a1" not in lab1.lab.harness.processes:
        lab1.start_dds_tool("spy-a1", ARM, "spy")
    before = _diag(client)
    rogue = lab1.start_dds_tool(
        "rogue-a1", ARM, "rogue", "--rate", str(RATE_HZ), "--for-s", str(ROGUE_S),
        "--forge", *map(str, FORGED),
    )  # fmt: skip
    time.sleep(1.0)
    command = move(client, 25.0, wait=False)
    stop = client.call("estop", arm=ARM, timeout_s=2.0, reason="row 4 under a rogue")
    wait_until(lambda: rogue.poll() is not None, ROGUE_S + 10.0)
    time.sleep(1.5)  # a diag period
    after = _diag(client)
    status, joints = client.call("snapshot", arms=[ARM])["arms"][ARM]
    ack = stop["acks"][ARM]
    holds = [
        c.angles_deg
        for _t, _seq, c in commands_seen(lab1.lab.log("spy-a1"), stop["stamp_ns"])
        if isinstance(c, protocol.SetAllAngles)
    ]
    run = {
        "alive": _alive(lab1),
        "command": command,
        "ack": ack,
        "received_ms": _stop_ms(stop, ack, "received_ns"),
        "written_ms": _stop_ms(stop, ack, "dds_written_ns"),
        "status": status,
        "malformed": after["malformed"] - before["malformed"],
        "unknown": after["unknown_messages"] - before["unknown_messages"],
        "moved_deg": max(abs(a - b) for a, b in zip(joints["angles_deg"], before_pose)),
        "real_after": [round(a, 1) for a in joints["angles_deg"]],
        "holds": holds,
        "sent": lab1.lab.log("rogue-a1").strip().splitlines()[-1],
    }
    print(
        f"\nrow 4, rogue on {ARM}'s DDS topics ({run['sent']}): command during it "
        f"ok={command['ok']} {command['error']}; stop received {run['received_ms']} ms, "
        f"written {run['written_ms']} ms, seen still {bool(ack and ack['still_ns'])}; diag "
        f"malformed +{run['malformed']}, unknown +{run['unknown']}; hold targets written after "
        f"the stop {[h[:3] for h in holds[:3]]}; real arm after the rogue {run['real_after']} "
        f"(was {[round(a, 1) for a in before_pose]}, forged {FORGED})"
    )
    return run


def _forgery(kind: LabKind, real: dict[str, Any]) -> tuple[float, str]:
    """(the forged value, what it says) against the device's ``real`` state: the gripper at
    the far end of its stroke (0 rad closed, 2 pi open), the G1 in another walking FSM."""
    if kind.name == "gripper":
        closed = real["q_rad"] > math.pi
        return (0.0, "fully closed") if closed else (2 * math.pi, "fully open")
    fsm = 801 if real["fsm_id"] != 801 else 500
    return float(fsm), f"walking: fsm {fsm} {loco.fsm_name(fsm)}, dynamic"


def _shows(kind: LabKind, state: dict[str, Any], forged: float) -> bool:
    """Whether a relayed state shows the forgery (the real G1 stands: static throughout)."""
    if kind.name == "gripper":
        return abs(state["q_rad"] - forged) < 0.5
    return state["fsm_id"] == int(forged) or state["fsm_mode"] == loco.DYNAMIC


def _seen(kind: LabKind, states: list[dict[str, Any]]) -> list[Any]:
    """What the relayed states showed: the gripper's lowest and highest position, the G1's
    (fsm_id, fsm_mode) pairs."""
    if kind.name == "gripper":
        q = [s["q_rad"] for s in states]
        return [round(min(q), 3), round(max(q), 3)] if q else []
    return sorted({(s["fsm_id"], s["fsm_mode"]) for s in states})


def device_command(kind: LabKind, real: dict[str, Any]) -> dict[str, Any]:
    """A command that leaves the device where it stands: the gripper to its own position; the
    G1's ``start`` (walking controller 500, its lab FSM), a mode switch its agent refuses in a
    dynamic state: it passes only if the agent believes the real, static state."""
    if kind.name == "gripper":  # in percent: a position read at an end may be past its limit
        return {"op": "move", "open_pct": min(100.0, max(0.0, round(real["opening_pct"], 2)))}
    return {"op": "start"}


def device_run(lab1: LabFleet, kind: LabKind) -> dict[str, Any]:
    """One forger against the lab's device of ``kind``, standing; what was seen."""
    client = lab1.clients["client"]
    restore(lab1, client)
    (unit,) = kind.units(lab1)
    host = lab1.devices[unit].host

    def state() -> dict[str, Any] | None:
        return client.call("device_state", unit=unit)["state"]  # type: ignore[no-any-return]

    wait_until(lambda: (s := state()) is not None and not kind.moving(s), 10.0)
    real = state()
    assert real is not None
    forged, says = _forgery(kind, real)
    before = _diag(client, unit)
    client.call("watch_start")
    client.call("watch_take")  # from here on
    name = f"rogue-{unit}"  # checks.restore: a rogue may have exited
    rogue = lab1.start_dds_tool(
        name, host, "forge", "--device", kind.name, "--state-topic", STATE_TOPICS[kind.name],
        "--value", str(forged), "--rate", str(FORGE_HZ), "--for-s", str(FORGE_S),
    )  # fmt: skip
    seen = [before]

    def flooded() -> bool:  # each diag call waits for the next (1 Hz)
        seen.append(_diag(client, unit, after_ns=seen[-1]["stamp_ns"]))
        return seen[-1]["foreign_feedback"] - before["foreign_feedback"] >= FLOOD_SEEN

    wait_until(flooded, 5.0)
    command = client.call("device_command", unit=unit, command=device_command(kind, real))
    stop = client.call("estop", arm=unit, timeout_s=2.0, reason=f"row 4 under a forged {unit}")
    wait_until(lambda: rogue.poll() is not None, FORGE_S + 10.0)
    lines = [json.loads(line) for line in lab1.lab.log(name).splitlines() if line.startswith("{")]
    ready = next(line["t_ns"] for line in lines if "ready" in line)
    done = next((line for line in lines if "done" in line), None)
    assert done is not None, f"{name} ended without its count:\n{lab1.lab.log(name)}"
    after = _diag(client, unit, after_ns=done["t_ns"])
    samples = [s for s in client.call("watch_take")["samples"] if s[1] == unit and s[2] == "state"]
    ack = stop["acks"][kind.label(unit)]
    during = [v for t, _u, _c, v in samples if ready <= t <= done["t_ns"]]
    latest = samples[-1][3] if samples else state()
    return {
        "unit": unit,
        "host": host,
        "alive": _alive(lab1),
        "command": command["reply"],
        "command_json": device_command(kind, real),
        "ack": ack,
        "received_ms": _stop_ms(stop, ack, "received_ns"),
        "written_ms": _stop_ms(stop, ack, "dds_written_ns"),
        "confirmed_ms": _stop_ms(stop, ack, "still_ns"),
        "confirmed_in_flood": bool(ack and ack["still_ns"] and ack["still_ns"] < done["t_ns"]),
        "latest": latest,
        "forged": forged,
        "says": says,
        "sent": done["forged"],
        "foreign": after["foreign_feedback"] - before["foreign_feedback"],
        "implausible": after["implausible_feedback"] - before["implausible_feedback"],
        "relayed": len(during),
        "seen": _seen(kind, during),
        "shown": [s for _t, _u, _c, s in samples if _shows(kind, s, forged)][:3],
        "real": real,
    }
