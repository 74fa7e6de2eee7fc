"""Access control and authentication on real routers: a fleet with mutual TLS and the access
control generated from its inventory (router, simulator, agent, coordinator as processes; the
test's clients are separate sessions with their own certificates).

Every forgery of the security review is tried by a principal that may connect but does not own
the key, and must be refused: the receiver is always another session (a session delivers its
own puts to itself locally, whatever the router decides).
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from fleet.client import FleetClient
from fleet.g1.messages import G1LowState, G1State
from fleet.heartbeat import Liveness
from fleet.inventory import Inventory, load_inventory
from fleet.security.certs import make_certs
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode, encode
from fleet.wire.payloads import G1_LOWSTATE, G1_STATE
from fleet.wire.session import Credentials, RouterUnreachable, open_client
from testkit.collect import Collector
from testkit.harness import FleetHarness, free_port, wait_until
from tests.e2e.test_demo import stop_demo


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FleetHarness]:
    """Two arms with mutual TLS and access control, shared by this module's tests."""
    with FleetHarness(tmp_path_factory.mktemp("secure"), arms=2, security="mtls") as h:
        h.start_router("--audit")
        h.start_sim()
        h.start_agent()
        h.start_coordinator()
        operator = h.client()
        wait_until(lambda: h.all_links_ok(operator), 30.0)
        yield h


class _Seen:
    """Payloads seen on one key expression by a session of ``principal``."""

    def __init__(self, client: FleetClient, key: str) -> None:
        self.items: list[bytes] = []
        self._lock = threading.Lock()
        self._sub = client.session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.items.append(sample.payload.to_bytes())

    def has(self, marker: bytes) -> bool:
        with self._lock:
            return any(marker in item for item in self.items)

    def close(self) -> None:
        self._sub.undeclare()


def _forged_not_delivered(forger: FleetClient, reader: FleetClient, key: str) -> None:
    """``forger`` puts a marked payload on ``key``; ``reader`` (another session that may read
    it) must never receive it, while the real publisher's samples keep arriving."""
    seen = _Seen(reader, key)
    try:
        time.sleep(0.3)
        marker = f"forged-{time.monotonic_ns()}".encode()
        for _ in range(5):
            forger.session.put(key, b'{"forged":"' + marker + b'"}')
            time.sleep(0.05)
        time.sleep(0.5)
        assert not seen.has(marker), f"a forged sample on {key} was delivered"
    finally:
        seen.close()


def test_the_secure_fleet_works_for_those_who_belong(secure: FleetHarness) -> None:
    operator = secure.client()
    assert operator.agents_alive() == {"a1", "a2"}  # the agents' liveliness tokens
    state = _Seen(operator, operator.keys.state)  # the coordinator hears the agents
    try:
        wait_until(lambda: state.has(b'"online":true'), 5.0)
    finally:
        state.close()
    # The coordinator's own view of every link: a synchronized move is refused while it knows
    # none ("its link is unknown": a fresh-clone run).
    wait_until(
        lambda: (
            (s := operator.fleet_state(wait_s=0.5)) is not None
            and all(a.online and a.link == "ok" for a in s.arms.values())
        ),
        10.0,
    )
    assert operator.multi("all", m.MoveJoint(joint=0, angle_deg=2.0, wait_reached=True)).ok


def test_commands_need_a_commander_role(secure: FleetHarness) -> None:
    operator, viewer = secure.client(), secure.client("viewer")
    move = m.MoveJoint(joint=0, angle_deg=8.0, wait_reached=True, owner="ann", takeover=True)
    reply = operator.command("a1", move)
    assert reply.ok, reply.error
    assert operator.command("a1", m.Release(owner="ann")).ok
    refused = viewer.command("a1", m.MoveJoint(joint=0, angle_deg=30.0))
    assert not refused.ok and refused.error is not None
    assert "access control" in refused.error.message
    refused_multi = viewer.multi("all", m.MoveJoint(joint=0, angle_deg=30.0))
    assert not refused_multi.ok
    _status, joints = operator.snapshot(["a1"])["a1"]
    assert joints is not None and abs(joints.angles_deg[0] - 8.0) < 2.0


def test_an_observer_may_stop_but_never_reset(secure: FleetHarness) -> None:
    operator, viewer = secure.client(), secure.client("viewer")
    acks = viewer.estop(timeout_s=5.0)
    assert all(a is not None and a.still_ns is not None for a in acks.values()), acks
    viewer.reset()
    time.sleep(1.0)
    statuses = operator.snapshot()
    assert all(s is not None and s.estopped for s, _j in statuses.values()), statuses
    operator.reset()
    wait_until(
        lambda: all(s is not None and not s.estopped for s, _j in operator.snapshot().values()),
        5.0,
    )


@pytest.mark.parametrize("channel", [keys.JOINTS, keys.STATUS, keys.CONTACT, keys.ESTOP_ACK])
def test_nobody_but_the_arms_agent_publishes_its_state(secure: FleetHarness, channel: str) -> None:
    # A forged contact once made the coordinator back off to the forger's target, forged
    # joints drove mirror followers: only agent-lo may publish a1's state now.
    maintainer, reader = secure.client("maintainer"), secure.client("viewer")
    _forged_not_delivered(maintainer, reader, maintainer.keys.arm("a1", channel))
    # Refused and logged: the router's audit names the principal and the key.
    key = maintainer.keys.arm("a1", channel)
    wait_until(
        lambda: any(
            "CertCommonName(maintainer)" in line and "unauthorized to Put" in line and key in line
            for line in secure.log("router").splitlines()
        ),
        3.0,
    )


def test_a_heartbeat_cannot_be_forged_for_another_principal(secure: FleetHarness) -> None:
    maintainer, reader = secure.client("maintainer"), secure.client()
    _forged_not_delivered(maintainer, reader, maintainer.keys.heartbeat_of("coordinator"))


def _free(operator: FleetClient, arm: str) -> None:
    """``arm`` unlatched and without a lease, as a test of a new owner needs it. An earlier test
    of this fleet may have left it stopped (at load 20 a coordinator's heartbeat gap trips the
    watchdog of an arm it commanded) or leased (a synchronized move leaves the coordinator's
    lease until it expires: lease_s, 3 s); neither is the subject."""
    operator.reset(arm)
    wait_until(
        lambda: (
            (s := operator.snapshot([arm])[arm][0]) is not None
            and not s.estopped
            and s.owner is None
        ),
        10.0,
    )


def test_a_lease_cannot_be_released_or_taken_by_another_principal(secure: FleetHarness) -> None:
    operator, maintainer = secure.client(), secure.client("maintainer")
    _free(operator, "a2")
    assert operator.command("a2", m.MoveJoint(joint=0, angle_deg=4.0, owner="ann")).ok
    refused = maintainer.command("a2", m.MoveJoint(joint=0, angle_deg=20.0, owner="bob"))
    assert refused.error is not None and refused.error.code == ErrorCode.LEASE_EXISTS
    # The 3207 message names the holder: releasing with that name is still someone else.
    assert "operator/ann" in refused.error.message
    forged = maintainer.command("a2", m.Release(owner="ann"))
    assert forged.error is not None and forged.error.code == ErrorCode.LEASE_INVALID
    assert operator.command("a2", m.Release(owner="ann")).ok


def test_a_third_party_beating_a_dead_players_name_does_not_keep_its_arms_unwatched(
    secure: FleetHarness,
) -> None:
    operator, maintainer = secure.client(), secure.client("maintainer")
    player = Liveness(operator.session, operator.keys, "player-7", operator.principal)
    impostor = Liveness(maintainer.session, maintainer.keys, "player-7", maintainer.principal)
    _free(operator, "a1")
    try:
        time.sleep(0.4)  # the agent hears the player before it moves the arm
        move = m.MoveJoint(joint=1, angle_deg=60.0, owner="player-7")
        assert operator.command("a1", move).ok
        player.close()  # the player dies; the impostor beats on with its name
        wait_until(
            lambda: (s := operator.snapshot(["a1"])["a1"][0]) is not None and s.estopped, 3.0
        )
        status = operator.snapshot(["a1"])["a1"][0]
        assert status is not None and "watchdog" in (status.stop_reason or "")
    finally:
        impostor.close()
        player.close()
    operator.reset()


def test_fault_injection_is_for_maintainers_only(secure: FleetHarness) -> None:
    operator, maintainer = secure.client(), secure.client("maintainer")
    fault = b'{"op":"noise","noise_deg":0.0,"jitter_s":0.0}'
    key = operator.keys.arm("a1", keys.SIM_FAULT)
    assert not [r for r in operator.session.get(key, payload=fault, timeout=2.0) if r.ok]
    assert [r for r in maintainer.session.get(key, payload=fault, timeout=5.0) if r.ok]


def test_oversized_payloads_are_dropped_at_the_router(secure: FleetHarness) -> None:
    operator, reader = secure.client(), secure.client("viewer")
    seen = _Seen(reader, operator.keys.estop)
    try:
        time.sleep(0.3)
        operator.session.put(operator.keys.estop, b'{"x":"' + b"z" * 8000 + b'"}')
        time.sleep(0.5)
        assert not seen.items, "an 8 KB stop crossed the router"
    finally:
        seen.close()


def test_strangers_cannot_connect(secure: FleetHarness, tmp_path: Path) -> None:
    # Plain TCP to a TLS endpoint, and a certificate from another CA with a known name.
    plain = [secure.endpoint.replace("tls/", "tcp/")]
    with pytest.raises(RouterUnreachable):
        open_client(plain, connect_timeout_s=2.0)
    make_certs(secure.inventory, tmp_path / "other", days=1)
    cert, key = str(tmp_path / "other/operator.pem"), str(tmp_path / "other/operator.key")
    stranger = Credentials(ca=str(tmp_path / "other/ca.pem"), cert=cert, key=key, mtls=True)
    with pytest.raises(RouterUnreachable):
        open_client([secure.endpoint], connect_timeout_s=2.0, credentials=stranger)


def test_password_mode_authenticates_users(tmp_path: Path) -> None:
    with FleetHarness(tmp_path, arms=1, security="password") as h:
        h.start_router()
        h.start_sim()
        h.start_agent()
        operator = h.client()
        wait_until(lambda: h.all_links_ok(operator), 30.0)
        assert operator.command("a1", m.MoveJoint(joint=0, angle_deg=3.0)).ok
        viewer = h.client("viewer")
        assert not viewer.command("a1", m.MoveJoint(joint=0, angle_deg=9.0)).ok
        wrong = Credentials(ca=h.inventory.security.ca, user="operator", password="guess")
        with pytest.raises(RouterUnreachable):
            open_client([h.endpoint], connect_timeout_s=2.0, credentials=wrong)


def _the_g1_is_posed_and_dances(inventory: Inventory, demo_output: Callable[[], str]) -> None:
    """The G1's lowstate reaches the operator (the router denied it to its agent: the G1 was
    never posed, and the dance, which waits for its pose, never started) and the dance takes
    the G1's arms (their weight ramps up). Not the ripple's keyframe: on a loaded host the
    agents' watchdog may stop the dance first (a player's heartbeat late by 0.5 s), as in any
    demo."""
    with FleetClient(inventory.with_principal("operator"), connect_timeout_s=10.0) as client:
        space = client.keys
        lows: Collector[G1LowState] = Collector(
            client.session, space.device("g1", "h1", keys.LOWSTATE), G1_LOWSTATE.decode
        )
        states: Collector[G1State] = Collector(
            client.session, space.device("g1", "h1", keys.STATE), G1_STATE.decode
        )
        try:
            wait_until(lambda: lows.items, 20.0, explain=lambda: demo_output()[-4000:])
            wait_until(
                lambda: any(s.arm_phase in ("engaging", "on") for s in states.items),
                60.0,
                explain=lambda: demo_output()[-4000:],
            )
        finally:
            lows.close()
            states.close()


def test_the_secure_demo_runs_end_to_end_and_its_printed_cli_command_works(
    tmp_path: Path, dds_domain: int
) -> None:
    """The secure demo prints its temporary inventory and a CLI command with it, and that
    command connects (it failed with "no Zenoh router answered": no certificate); the arms'
    calibration files are found from the temporary copy (``calib NONE`` before); its G1 is
    posed and the dance takes its arms."""
    port, domain = free_port(), dds_domain
    inventory = tmp_path / "inventory.toml"
    inventory.write_text(
        (Path(__file__).resolve().parents[2] / "inventory.toml").read_text(encoding="utf-8")
    )
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "a1.json").write_text("{}")
    out = tmp_path / "demo.out"
    with open(out, "wb") as sink:
        demo = subprocess.Popen(
            [sys.executable, "-m", "fleet.cli.main", "demo", "--secure", "--no-viewer"]
            + ["--for-s", "240", "--domain", str(domain), "--endpoint", f"tcp/127.0.0.1:{port}"]
            + ["--inventory", str(inventory)],
            stdout=sink,
            stderr=subprocess.STDOUT,
            cwd=Path(__file__).resolve().parents[2],
        )
    try:
        text = lambda: out.read_text(errors="replace")  # noqa: E731
        try_line = wait_until(
            lambda: next((ln for ln in text().splitlines() if ln.startswith("try: ")), None),
            30.0,
        )
        assert f"tls/127.0.0.1:{port}" in try_line, text()
        argv = try_line.removeprefix("try: ").split()
        assert argv[0].endswith("fleet") and argv[1] == "status", try_line
        secure = Path(argv[argv.index("--inventory") + 1])
        assert f"{secure}" in text()  # "inventory with the certificates ...: <path>"
        assert load_inventory(secure).calibration_path("a1").resolve() == (
            tmp_path / "calibration" / "a1.json"
        )

        def status_ok() -> str | None:
            run = subprocess.run(
                [sys.executable, "-m", "fleet.cli.main", *argv[1:]],
                capture_output=True,
                text=True,
                timeout=30,
            )
            return run.stdout if run.returncode == 0 else None

        last = wait_until(status_ok, 40.0, interval_s=1.0)
        rows = [line.split() for line in last.splitlines()[1:4]]
        assert [r[:3] for r in rows] == [["a1", "up", "ok"], ["a2", "up", "ok"], ["a3", "up", "ok"]]
        _the_g1_is_posed_and_dances(
            load_inventory(secure).with_endpoints([f"tls/127.0.0.1:{port}"]), text
        )
    finally:
        stop_demo(demo)


def test_a_players_choreography_state_reaches_observers_and_cannot_be_forged(
    secure: FleetHarness,
) -> None:
    operator, viewer = secure.client(), secure.client("viewer")
    seen = _Seen(viewer, viewer.keys.choreo)
    try:
        marker = f"dance-{time.monotonic_ns()}"
        status = m.ChoreoStatus(1, "p1", marker, "aborted", "a1 stopped", 0, "ready")

        def delivered() -> bool:
            operator.session.put(operator.keys.choreo_of(operator.principal), encode(status))
            return seen.has(marker.encode())

        wait_until(delivered, 10.0)
    finally:
        seen.close()
    _forged_not_delivered(secure.client("maintainer"), viewer, viewer.keys.choreo_of("operator"))
