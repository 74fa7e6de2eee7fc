"""Unitree's own Python SDK (``unitree_sdk2py``, packaged as ``unitree-sdk2py-dimos``) as the
far side of the G1 tests, each role in a process of its own (the SDK's ``ChannelFactory`` is a
process-wide singleton bound to one domain):

- ``client``: its ``LocoClient`` drives a G1 (our simulator) through a scripted walk, continuous
  gait and damp; prints one JSON object of what each call returned and what state followed.
- ``server``: a fake G1 built on its RPC ``Server`` (handlers for the LocoClient API ids) that
  publishes ``rt/sportmodestate`` with its ``ChannelPublisher`` (``--no-state``: firmware
  before 1.5.1, none); prints one JSON line per call it handled. With ``--arms`` it also
  publishes ``rt/lowstate`` (the SDK's ``LowState_``, sealed with the SDK's ``CRC``, with
  ``--mode-machine``; every ``--bad-lowstate-every``-th sample's CRC broken, one line each) and
  prints one line per ``rt/arm_sdk`` message its ``ChannelSubscriber`` took: the weight, whether
  the SDK's CRC agrees, the waist yaw, the mode_machine, when (monotonic). The pose it reports
  blends the last message it took by that message's weight, and keeps it when the messages stop
  (as the robot keeps a stream's weight when its writer goes away): an agent restarted beside it
  finds the arms where the previous one left them. Each call's line says when it came too.

The SDK chooses the service name from ``LOCO_SERVICE_NAME`` (``sport`` in its ``g1_loco_api``),
which ``LocoClient.__init__`` reads from its own module: ``--service loco`` sets that module's
name before the client is built, as a program for ai_sport < 8.2 would. The SDK's
configuration (``ChannelConfigHasInterface``: multicast on the named card) is replaced by the
test's (loopback, unicast peers, no multicast); its channels, QoS, stubs and threads run as
shipped.
"""

from __future__ import annotations

import argparse
import itertools
import json
import signal
import sys
import threading
import time
from typing import Any

from fleet.d1 import dds

STATE_TOPIC = "rt/sportmodestate"


_EMIT_LOCK = threading.Lock()


def _emit(record: object) -> None:
    """One JSON line on stdout, whole: ``print`` writes the text and its newline apart, and
    the RPC server's and the arm_sdk reader's lines interleaved (``{...}{...}``: a test read
    a stop's StopMove call as undecodable)."""
    with _EMIT_LOCK:
        sys.stdout.write(json.dumps(record) + "\n")
        sys.stdout.flush()


def init_sdk(domain: int) -> None:
    """The SDK's ChannelFactory on ``domain``, on loopback with unicast discovery."""
    from unitree_sdk2py.core import channel

    channel.ChannelConfigHasInterface = dds.cyclonedds_config("lo", ["127.0.0.1"])
    channel.ChannelFactoryInitialize(domain, "lo")


def loco_client(service: str) -> Any:
    """The SDK's LocoClient on ``service`` (its own selection: the module's name)."""
    from unitree_sdk2py.g1.loco import g1_loco_client

    g1_loco_client.LOCO_SERVICE_NAME = service
    client = g1_loco_client.LocoClient()
    client.SetTimeout(2.0)
    client.Init()
    return client


class StateWatch:
    """The newest rt/sportmodestate, through the SDK's ChannelSubscriber."""

    def __init__(self) -> None:
        from unitree_dds_wrapper.idl.unitree_hg.msg import dds_ as hg
        from unitree_sdk2py.core.channel import ChannelSubscriber

        self._lock = threading.Condition()
        self.latest: Any = None
        self._subscriber = ChannelSubscriber(STATE_TOPIC, hg.SportModeState_)
        self._subscriber.Init(self._on_state, 10)

    def _on_state(self, sample: Any) -> None:
        with self._lock:
            self.latest = sample
            self._lock.notify_all()

    def wait(self, predicate: Any, timeout_s: float) -> float | None:
        """Seconds until ``predicate(latest)`` held, None if it did not within ``timeout_s``."""
        start = time.monotonic()
        with self._lock:
            ok = self._lock.wait_for(
                lambda: self.latest is not None and predicate(self.latest), timeout_s
            )
        return time.monotonic() - start if ok else None


def run_client(args: argparse.Namespace) -> int:
    """The scripted session; one JSON object on stdout."""
    init_sdk(args.domain)
    watch = StateWatch()
    client = loco_client(args.service)
    out: dict[str, Any] = {"service": client._ClientBase__stub._ClientStub__serviceName}
    out["state_s"] = watch.wait(lambda s: True, 20.0)
    code, data = client._Call(7001, "{}")  # GetFsmId (this SDK has no wrapper for it)
    out["get_fsm_id"] = [code, data]
    out["walk"] = client.SetVelocity(0.3, 0.0, 0.0, 3.0)
    out["walk_dynamic_s"] = watch.wait(lambda s: s.fsm_mode == 1, 3.0)
    out["stand_up_while_dynamic"] = client.SetFsmId(4)
    out["continuous_on"] = client.SetBalanceMode(1)
    out["balance_mode"] = list(client._Call(7003, "{}"))
    out["stop_move"] = client.SetVelocity(0.0, 0.0, 0.0)  # StopMove() returns nothing
    # Continuous gait: StopMove alone leaves it stepping (bounded look, 3 x the sim's settle).
    out["static_after_stop_move_s"] = watch.wait(lambda s: s.fsm_mode == 0, 0.9)
    out["continuous_off"] = client.SetBalanceMode(0)  # ContinuousGait(false) / BalanceStand
    out["static_after_continuous_off_s"] = watch.wait(lambda s: s.fsm_mode == 0, 3.0)
    out["damp"] = client.SetFsmId(1)  # Damp() returns nothing
    out["damped_s"] = watch.wait(lambda s: s.fsm_id == 1, 3.0)
    out["set_task_id"] = client.SetTaskId(1)  # WaveHand(turn_flag=True), from damping: 3205
    _emit(out)
    return 0


def run_server(args: argparse.Namespace) -> int:
    """A fake G1 on the SDK's RPC Server until SIGTERM."""
    from unitree_dds_wrapper.idl.unitree_hg.msg import dds_ as hg
    from unitree_sdk2py.core.channel import ChannelPublisher
    from unitree_sdk2py.rpc.server import Server

    from fleet.g1 import loco
    from fleet.g1.sim import G1Model

    init_sdk(args.domain)
    model = G1Model(500, args.settle)
    lock = threading.Lock()
    stop = threading.Event()

    def handler(api_id: int) -> Any:
        def handle(parameter: str) -> tuple[int, str]:
            with lock:
                code, data = model.call(api_id, parameter, time.monotonic())
            _emit({"api_id": api_id, "parameter": parameter, "code": code, "t": time.monotonic()})
            return code, data

        return handle

    server = Server(args.service)
    for api_id in sorted(loco.API_IDS):
        server._RegistHandler(api_id, handler(api_id), False)
    server.Start()
    publisher = ChannelPublisher(STATE_TOPIC, hg.SportModeState_)
    publisher.Init()
    lowstate = _arms(lock, model, args.mode_machine, args.bad_lowstate_every) if args.arms else None
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    _emit({"ready": args.service, "state": not args.no_state})
    while not stop.wait(0.01):  # 100 Hz, the G1's sportmodestate rate is not in the seeds
        if args.no_state:
            continue
        with lock:
            now = time.monotonic()
            sample = hg.SportModeState_(model.fsm_id, model.fsm_mode(now), 0, 0.0)
        publisher.Write(sample)
        if lowstate is not None:
            lowstate()
    return 0


def _arms(lock: threading.Lock, model: Any, mode_machine: int, bad_every: int) -> Any:
    """rt/arm_sdk watched (one JSON line a message), rt/lowstate published: returns the
    function that publishes one (the pose blends the arm_sdk targets by their weight)."""
    from unitree_sdk2py.core.channel import ChannelPublisher, ChannelSubscriber
    from unitree_sdk2py.idl.default import unitree_hg_msg_dds__LowState_
    from unitree_sdk2py.idl.unitree_hg.msg.dds_ import LowCmd_, LowState_
    from unitree_sdk2py.utils.crc import CRC

    crc = CRC()
    pose = [0.0] * 29

    def on_cmd(cmd: Any) -> None:
        weight = float(cmd.motor_cmd[29].q)
        ok = cmd.crc == crc.Crc(cmd)
        line = {"arm": round(weight, 4), "crc_ok": ok, "t": time.monotonic()}
        line["q12"] = round(float(cmd.motor_cmd[12].q), 4)
        line["mode_machine"] = int(cmd.mode_machine)
        _emit(line)
        with lock:
            if ok and model.fsm_id in (4, 500, 501):
                for i in range(12, 29):
                    pose[i] = weight * float(cmd.motor_cmd[i].q)

    subscriber = ChannelSubscriber("rt/arm_sdk", LowCmd_)
    subscriber.Init(on_cmd, 10)
    writer = ChannelPublisher("rt/lowstate", LowState_)
    writer.Init()

    published = itertools.count(1)
    bad = itertools.count(1)

    def publish() -> None:
        state = unitree_hg_msg_dds__LowState_()
        state.mode_machine = mode_machine
        with lock:
            for i, q in enumerate(pose):
                state.motor_state[i].q = q
        state.crc = crc.Crc(state)
        if bad_every and next(published) % bad_every == 0:
            state.crc ^= 1  # a corrupted sample, as a flipped bit on the wire
            _emit({"bad_lowstate": next(bad), "t": time.monotonic()})
        writer.Write(state)

    publish.keep = (subscriber, writer)  # type: ignore[attr-defined]
    return publish


def main() -> int:
    """``python -m testkit.sdk_g1 client|server --domain N --service sport|loco``."""
    parser = argparse.ArgumentParser(prog="sdk_g1")
    parser.add_argument("role", choices=("client", "server"))
    parser.add_argument("--domain", type=int, required=True)
    parser.add_argument("--service", choices=("sport", "loco"), default="sport")
    parser.add_argument("--settle", type=float, default=0.3)
    parser.add_argument("--no-state", action="store_true")
    parser.add_argument("--arms", action="store_true")
    parser.add_argument("--mode-machine", type=int, default=0)
    parser.add_argument("--bad-lowstate-every", type=int, default=0)
    args = parser.parse_args()
    return run_client(args) if args.role == "client" else run_server(args)


if __name__ == "__main__":
    sys.exit(main())
