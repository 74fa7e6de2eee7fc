"""Hostile input on the key space, against real processes: a router, two simulated arms, one
agent per arm and a coordinator. Each test performs one attack of the security review, then
proves the fleet still stops (every arm acknowledges a fleet stop in normal time and is seen
still) and still serves (a valid command works). Before the fix each attack disabled the stop,
killed a process or made the coordinator report a dead fleet.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator

import pytest
import zenoh

from fleet.client import FleetClient
from fleet.wire import keys
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode
from fleet.wire.payloads import DIAG
from fleet.wire.session import close_bounded, open_client
from testkit.harness import FleetHarness, free_port, wait_until
from testkit.hostile import (
    HOSTILE_CHUNKS,
    INVALID_KEYS,
    POISONS,
    ROUTER_DROPS,
    alive,
    assert_fleet_stops_and_serves,
    decode,
    latest,
    put,
    rss_mb,
    statuses,
    wait_reset,
)
from testkit.kinds import DEVICES, KIND_IDS, KINDS, Kind, LatchWatch, send
from tests.e2e.test_metrics import scrape, value

ARMS = ["a1", "a2"]
FLOOD_BOUND_MS = 1000.0


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[FleetHarness, FleetClient]]:
    """Router, simulator, one agent per arm and a coordinator, shared by this module's tests
    (each test ends by proving the fleet healthy, so the next starts from a working fleet)."""
    # a2 detects no contact: a stalled joint then waits for its target instead of being
    # force-limited (the long-request test needs requests that really take long).
    no_contact = "[arms.a2.contact]\nenabled = false\n"
    with FleetHarness(tmp_path_factory.mktemp("hostile"), arms=2, extra=no_contact) as harness:
        harness.start_router()
        harness.start_sim()
        harness.start_agent("a1", name="agent1")
        harness.start_agent("a2", name="agent2")
        harness.start_coordinator()
        client = harness.client()
        wait_until(lambda: harness.all_links_ok(client), 30.0)
        wait_until(lambda: _state(client) is not None, 15.0)
        yield harness, client


def _state(client: FleetClient) -> m.FleetState | None:
    data = latest(client, client.keys.state)
    return None if data is None else decode(m.FleetState, data)  # type: ignore[return-value]


@pytest.mark.parametrize("poison", sorted(POISONS))
def test_a_poison_stop_still_stops_and_never_disables_the_stop(
    fleet: tuple[FleetHarness, FleetClient], poison: str
) -> None:
    harness, client = fleet
    wait_reset(client, ARMS)
    put(client, client.keys.estop, POISONS[poison])
    if poison in ROUTER_DROPS:
        # Dropped at the router: a1 stays as it was (checked after a2's stop and standstill,
        # put behind it on the same session, and on statuses published after that).
        assert client.estop(arm="a2", timeout_s=5.0)["a2"] is not None
        assert statuses(client, ["a1"])["a1"] is not None
        assert not statuses(client, ["a1"])["a1"].estopped  # type: ignore[union-attr]
        assert_fleet_stops_and_serves(harness, client)
        return
    # Fail safe: anyone may stop, so a stop that does not decode stops every arm.
    wait_until(
        lambda: all(
            s is not None and s.estopped and "undecodable" in (s.stop_reason or "")
            for s in statuses(client, ARMS).values()
        ),
        5.0,
    )
    put(client, client.keys.arm("a2", keys.ESTOP), POISONS[poison])
    assert_fleet_stops_and_serves(harness, client)


@pytest.mark.parametrize("poison", sorted(POISONS))
def test_poison_on_reset_and_heartbeat_changes_nothing(
    fleet: tuple[FleetHarness, FleetClient], poison: str
) -> None:
    harness, client = fleet
    acks = client.estop(arm="a1", timeout_s=5.0)
    assert acks["a1"] is not None
    heartbeat = client.keys.heartbeat_of(client.principal)
    for key in (client.keys.reset, client.keys.arm("a1", keys.RESET), heartbeat):
        put(client, key, POISONS[poison])
    time.sleep(0.5)
    # A reset that does not decode releases nothing.
    status = statuses(client, ["a1"])["a1"]
    assert status is not None and status.estopped
    assert_fleet_stops_and_serves(harness, client)


def test_poison_reports_never_blind_the_coordinator(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = fleet
    for channel in (keys.STATUS, keys.CONTACT, keys.ESTOP_ACK):
        for payload in POISONS.values():
            put(client, client.keys.arm("a1", channel), payload, every_one=True)
        put(client, client.keys.arm("zz-not-an-arm", channel), POISONS["nested"], every_one=True)
    time.sleep(1.5)  # longer than offline_after_s: a dead events thread shows every arm offline
    state = _state(client)
    assert state is not None
    assert all(state.arms[arm].online for arm in ARMS), state

    # Diag is published at 1 Hz: on a loaded host the newest one may predate the last puts.
    # 12 bad reports reach it (the router drops the 1 MiB ones) and 3 for an unknown arm.
    seen: list[m.CoordinatorDiag] = []

    def counted() -> bool:
        seen.append(decode(m.CoordinatorDiag, latest(client, client.keys.coordinator_diag)))  # type: ignore[arg-type]
        return seen[-1].bad_events >= 12 and seen[-1].unknown_arms >= 3

    try:
        wait_until(counted, 10.0, interval_s=0.5)
    except AssertionError:
        raise AssertionError(f"bad reports not all counted; the diags seen: {seen}") from None
    assert_fleet_stops_and_serves(harness, client)


def _get_all(client: FleetClient, key: str, payload: bytes) -> list[m.CommandReply]:
    replies = []
    # QueryTarget.ALL: every agent's queryable answers (the default asks only the best match).
    everyone = zenoh.QueryTarget.ALL
    for reply in client.session.get(key, payload=payload, timeout=5.0, target=everyone):
        if reply.ok is not None:
            replies.append(decode(m.CommandReply, reply.ok.payload.to_bytes()))
    return replies  # type: ignore[return-value]


def test_a_poison_command_is_refused_and_no_agent_dies(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = fleet
    everyone = client.keys.command("*", client.principal)
    for name, payload in POISONS.items():
        replies = _get_all(client, everyone, payload)
        if name in ROUTER_DROPS:  # no agent ever sees it: no answer at all
            assert replies == [], (name, replies)
            continue
        assert sorted(r.arm for r in replies) == ARMS, (name, replies)
        assert all(r.error and r.error.code == ErrorCode.PARAMETER for r in replies), replies
    (unknown,) = _get_all(client, client.command_key("a1"), b'{"op":"fly","to":"moon"}')
    assert unknown.error is not None and unknown.error.code == ErrorCode.NOT_IMPLEMENTED
    assert "fly" in unknown.error.message
    assert_fleet_stops_and_serves(harness, client)


@pytest.mark.timing
def test_a_heartbeat_flood_never_delays_a_stop_or_grows_memory(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = fleet
    wait_reset(client, ARMS)
    agent = harness.processes["agent1"].pid
    before_mb = rss_mb(agent)
    flooding = threading.Event()
    sent = [0]

    def flood() -> None:
        # A few sources, each beat repeating fresh stops for our arms: a latch (a DDS write,
        # acks, status) per beat if every beat were acted on; only the newest per source is.
        with open_client(client.inventory.endpoints) as s:
            publisher = s.declare_publisher(client.keys.heartbeat_of(client.principal))
            deadline = time.monotonic() + 6.0
            while not flooding.is_set() and time.monotonic() < deadline:
                n = sent[0]
                stops = {
                    arm: m.StopRequest(time.time_ns(), "flood", f"flood-{arm}-{n}") for arm in ARMS
                }
                beat = m.Heartbeat(time.time_ns(), f"flood-{n % 8}", n, 0.1, stops)
                publisher.put(m.encode(beat))
                sent[0] += 1

    thread = threading.Thread(target=flood, name="flood", daemon=True)
    thread.start()
    try:
        time.sleep(2.0)
        request = client.stop_request(reason="under a heartbeat flood", source="hostile-suite")
        acks = client.estop(timeout_s=5.0, request=request, wait_still=False)
    finally:
        flooding.set()
        thread.join(timeout=10.0)
    delays = {a: (k.received_ns - request.stamp_ns) / 1e6 for a, k in acks.items() if k}
    assert len(delays) == len(ARMS), acks
    # 1-2 ms on a quiet host, 3-5 s before the fix; the flood itself loads both cores here.
    assert max(delays.values()) <= FLOOD_BOUND_MS, (
        f"stop acted on after {delays} ms under the flood"
    )
    grown = rss_mb(agent) - before_mb
    print(f"flood: {sent[0]} heartbeats, stop delays {delays} ms, agent RSS +{grown:.1f} MB")
    assert grown < 40.0, f"the agent grew {grown:.0f} MB under {sent[0]} heartbeats"
    assert_fleet_stops_and_serves(harness, client)


def test_oversized_and_invented_names_are_never_stored(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = fleet
    wait_reset(client, ARMS)
    # A 1 MB stop id still stops (undecodable: anyone may stop) but is never repeated.
    put(client, client.keys.estop, POISONS["1MiB"])
    # Stops for arms that do not exist must not accumulate in the heartbeat.
    for i in range(300):
        put(client, client.keys.arm(f"ghost{i}", keys.ESTOP), m.encode(client.stop_request()))
    time.sleep(1.0)
    beat = latest(client, client.keys.heartbeat)
    assert beat is not None and len(beat) < 4096, f"heartbeat of {len(beat or b'')} bytes"
    heartbeat = decode(m.Heartbeat, beat)
    assert set(heartbeat.stops) <= {"*", *ARMS}, heartbeat.stops  # type: ignore[attr-defined]
    # An ack forged on a1's key naming a2 is a1's (the key says which arm).
    request = client.stop_request(source="hostile-suite")
    client.put_stop(request, "a1")
    forged = m.StopAck("a2", request.stop_id, "hold", time.time_ns(), None)
    reports: list[m.StopReport] = []
    sub = client.session.declare_subscriber(
        client.keys.stop_report,
        lambda s: reports.append(decode(m.StopReport, s.payload.to_bytes())),  # type: ignore[arg-type]
    )
    try:
        time.sleep(0.3)
        put(client, client.keys.arm("a1", keys.ESTOP_ACK), m.encode(forged))
        time.sleep(0.5)
    finally:
        sub.undeclare()
    mine = [r for r in reports if r.stop_id == request.stop_id]
    assert mine and all(set(r.arms) <= {"a1"} for r in mine), mine
    client.reset()
    assert_fleet_stops_and_serves(harness, client)


def test_a_query_flood_is_answered_busy_never_dropped(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = fleet
    wait_reset(client, ARMS)
    key = client.command_key("a1")
    # Valid holds: each is written and waits for the arm's acks, so the queue fills.
    handlers = [
        client.session.get(key, payload=m.encode(m.Hold()), timeout=10.0) for _ in range(1000)
    ]
    answered = 0
    codes: dict[int, int] = {}
    for handler in handlers:
        for reply in handler:
            if reply.ok is not None:
                answered += 1
                got = decode(m.CommandReply, reply.ok.payload.to_bytes())
                code = got.error.code if got.error else 0  # type: ignore[attr-defined]
                codes[code] = codes.get(code, 0) + 1
    print(f"1000 queries at once: {answered} answered, codes {codes}")
    assert answered == 1000, codes
    # Served (0) or answered busy (4003). A hold whose arm acknowledged it later than
    # recv_ack_timeout_s is answered 3104, truthfully: on this 2-core host, busy with the flood,
    # the simulated arm did so once in 1000 (one full run of four).
    assert set(codes) <= {0, ErrorCode.BUSY, ErrorCode.TIMEOUT}, codes
    assert codes.get(ErrorCode.TIMEOUT, 0) <= 10, codes
    assert_fleet_stops_and_serves(harness, client)


def test_a_queryable_that_never_answers_delays_no_command_reply(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    """A process declares every arm's command key and the coordinator's, takes each query and
    never answers it (a frozen or hostile process; in the network lab, a route left stale by a
    session that reconnected under loss). The genuine replies must not wait for it: with
    Zenoh's default consolidation each one arrived at its query's timeout (a command 5 s, a
    synchronized move 5 s through the coordinator's own command queries)."""
    harness, client = fleet
    wait_reset(client, ARMS)
    held: list[zenoh.Query] = []
    mute = open_client([harness.endpoint])
    try:
        for key in (client.keys.all_arms(keys.CMD) + "/*", client.keys.coordinator_cmd):
            mute.declare_queryable(key, held.append)
        wait_until(lambda: _held_one(client, held), 10.0)
        started = time.monotonic()
        reply = client.command("a1", m.Hold())
        command_s = time.monotonic() - started
        move = m.MoveJoint(joint=0, angle_deg=5.0)
        started = time.monotonic()
        multi = client.multi("all", move)
        multi_s = time.monotonic() - started
        print(f"with a mute queryable: command replied in {command_s:.3f} s, a move of both arms")
        print(f"through the coordinator in {multi_s:.3f} s; {len(held)} queries held")
        assert reply.ok, reply
        assert multi.ok, multi
        # A reply held to the timeout takes 5 s (3 + REPLY_MARGIN_S); half of that is far off.
        assert command_s < 2.5 and multi_s < 2.5, (command_s, multi_s)
    finally:
        held.clear()
        close_bounded(mute, "mute queryable session")
    client.reset()
    assert_fleet_stops_and_serves(harness, client)


def _held_one(client: FleetClient, held: list[zenoh.Query]) -> bool:
    """The mute queryable's declaration reached the router: a query to a1 reaches it."""
    before = len(held)
    client.command("a1", m.Hold())
    return len(held) > before


def test_every_agent_and_the_coordinator_survive_and_diag_counts(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = fleet
    wait_reset(client, ARMS)
    # Its own poison first: under xdist this module's tests may share their fleet with
    # another worker's, or run alone on it.
    put(client, client.unit_key("a1", keys.ESTOP), POISONS["not-json"])

    def counted() -> m.Diag | None:
        data = latest(client, client.keys.arm("a1", keys.DIAG), wait_s=1.5)
        diag = None if data is None else decode(m.Diag, data)
        return diag if diag is not None and diag.undecodable_stops > 0 else None  # type: ignore[attr-defined]

    diag = wait_until(counted, 10.0)
    assert diag.bad_payloads > 0 and diag.undecodable_stops > 0, diag  # type: ignore[attr-defined]
    assert all(code is None for code in alive(harness).values()), alive(harness)
    client.reset()
    assert_fleet_stops_and_serves(harness, client)


@pytest.mark.timing
def test_bad_input_is_in_the_next_diag_at_once_and_a_flood_makes_few(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    """A diag comes every second, and one more, within 0.2 s, when bad input was counted;
    a flood of bad input makes no more than 5 a second."""
    _harness, client = fleet
    arrived: list[tuple[float, m.Diag]] = []
    lock = threading.Lock()

    def on_diag(sample: zenoh.Sample) -> None:
        diag = decode(m.Diag, sample.payload.to_bytes())
        with lock:
            arrived.append((time.monotonic(), diag))  # type: ignore[arg-type]

    subscriber = client.session.declare_subscriber(client.keys.arm("a1", keys.DIAG), on_diag)
    try:
        wait_until(lambda: len(arrived) >= 2, 5.0)  # the periodic ones: the next is 1 s away
        with lock:
            last_s, last = arrived[-1]
        put(client, client.unit_key("a1", keys.RESET), POISONS["not-json"])
        counted = wait_until(
            lambda: next((a for a in list(arrived) if a[1].bad_payloads > last.bad_payloads), None),
            5.0,
        )
        # The periodic diag would come 1.0 s after the last; this one 0.2-0.3 s after it.
        assert counted[0] - last_s < 0.8, (counted[0] - last_s, len(arrived))
        flood_started = time.monotonic()
        for _ in range(100):  # 2 s of bad input, 50 a second
            put(client, client.unit_key("a1", keys.RESET), POISONS["not-json"])
            time.sleep(0.02)
        flood_s = time.monotonic() - flood_started
        with lock:
            during = [t for t, _d in arrived if flood_started <= t <= flood_started + flood_s]
        assert len(during) <= flood_s / 0.2 + 2, (len(during), flood_s)
        assert len(during) >= 3, (len(during), flood_s)  # it did publish early, not 1 a second
    finally:
        subscriber.undeclare()


@pytest.mark.timing
def test_long_multi_arm_requests_never_queue_without_bound(
    fleet: tuple[FleetHarness, FleetClient],
) -> None:
    harness, client = fleet
    wait_reset(client, ARMS)
    fault = client.keys.arm("a2", keys.SIM_FAULT)
    stall = b'{"op":"stall","joint":0,"angle_deg":0.0}'
    assert [r for r in client.session.get(fault, payload=stall) if r.ok is not None]
    try:
        # Each request waits (up to 4 s) for a target the stalled joint never reaches.
        blocked = m.MoveJoint(joint=0, angle_deg=30.0, wait_reached=True, timeout_s=4.0)
        request = m.encode(m.MultiArmRequest(target="a2", command=blocked))
        started = time.monotonic()
        arrived: list[tuple[float, bytes]] = []

        def on_reply(reply: zenoh.Reply) -> None:  # when each answer arrives, not when read
            if reply.ok is not None:
                arrived.append((time.monotonic() - started, reply.ok.payload.to_bytes()))

        for _ in range(10):
            client.session.get(
                client.keys.coordinator_command(client.principal),
                on_reply,
                payload=request,
                timeout=15.0,
            )
        wait_until(lambda: len(arrived) == 10, 15.0)
        answers = [(t, decode(m.MultiArmReply, data)) for t, data in arrived]
        busy = [t for t, r in answers if r.error and "busy" in r.error.message]  # type: ignore[attr-defined]
        served = [(t, r) for t, r in answers if not (r.error and "busy" in r.error.message)]  # type: ignore[attr-defined]
        print(f"10 long requests: {len(busy)} busy, answered after {[round(t, 1) for t in busy]} s")
        assert len(answers) == 10 and busy and max(busy) < 3.0, answers
        # A served request that ended before the last "busy" answer freed its worker for another
        # (on a host loaded to 10, an ack later than recv_ack_timeout_s ends one in milliseconds).
        freed = [r for t, r in served if t < max(busy)]
        assert len(served) <= 4 + len(freed), served
        assert len(busy) >= 10 - 4 - len(freed), answers
        diag = decode(m.CoordinatorDiag, latest(client, client.keys.coordinator_diag, 2.5))
        assert diag.busy >= len(busy), diag  # type: ignore[attr-defined]
    finally:
        unstall = b'{"op":"clear"}'
        assert [r for r in client.session.get(fault, payload=unstall) if r.ok is not None]
    client.command("a2", m.Release(owner=_state(client).coordinator))  # type: ignore[union-attr]
    assert_fleet_stops_and_serves(harness, client)


# ---------------------------------------------------------------- hostile command keys, every kind


@pytest.fixture(scope="module")
def kinds_fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FleetHarness]:
    """Router, simulators, one agent serving an arm, its gripper and a G1 (with metrics), and a
    coordinator: every command queryable of the fleet."""
    with FleetHarness(tmp_path_factory.mktemp("hostile-kinds"), arms=1, extra=DEVICES) as harness:
        harness.start_router()
        harness.start_sim()
        harness.metrics_port = free_port()  # type: ignore[attr-defined]
        agent = ["-m", "edge_agent", "--interface", "lo"]
        harness.start("agent", [*agent, "--metrics-port", str(harness.metrics_port)])  # type: ignore[attr-defined]
        harness.start_coordinator()
        client = harness.client()
        for kind in KINDS:
            wait_until(LatchWatch(client, kind).link_ok, 30.0)
        wait_until(lambda: _state(client) is not None, 15.0)
        yield harness


def _answers(client: FleetClient, key: str, payload: bytes) -> list[dict[str, object]]:
    """Every answer to a query on ``key``, ok or error replies alike, as JSON objects."""
    everyone = zenoh.QueryTarget.ALL
    got = []
    for reply in client.session.get(key, payload=payload, timeout=3.0, target=everyone):
        sample = reply.ok if reply.ok is not None else reply.err
        got.append(json.loads(sample.payload.to_bytes()))
    return got


def _bad_keys(client: FleetClient, unit: str) -> int | None:
    """The agent's count of queries on keys naming no usable principal, from ``unit``'s diag
    (None before a diag arrived)."""
    data = latest(client, client.unit_key(unit, keys.DIAG), wait_s=1.5)
    return None if data is None else DIAG.decode(data).bad_keys


def _counted_bad_keys(client: FleetClient, unit: str) -> int:
    """The count in ``unit``'s next diag."""
    counts: list[int] = []

    def diag_arrived() -> bool:
        count = _bad_keys(client, unit)
        counts.extend([] if count is None else [count])
        return bool(counts)

    wait_until(diag_arrived, 10.0)
    return counts[0]


@pytest.mark.parametrize("kind", KINDS, ids=KIND_IDS)
def test_a_command_key_naming_no_principal_is_answered_and_counted(
    kinds_fleet: FleetHarness, kind: Kind
) -> None:
    """A query on ``<kind>/<unit>/cmd/<chunk>`` whose last chunk is no usable name (dots, a
    wildcard, ``$*``, 1000 characters, unicode, a space) gets one clear error from the unit's
    agent, which keeps serving and counts each one in its diag and metrics. Before the fix the
    agent's reply raised ("does not intersect with query") and the agent exited at the first."""
    harness = kinds_fleet
    client = harness.client()
    client.reset(kind.unit)
    before = _counted_bad_keys(client, kind.unit)
    payload = m.encode(client.stamp(kind.moves()))
    for name, chunk in HOSTILE_CHUNKS.items():
        key = f"{client.unit_key(kind.unit, keys.CMD)}/{chunk}"
        answers = _answers(client, key, payload)
        assert len(answers) == 1, (name, answers)
        error = answers[0]["error"]
        assert answers[0]["ok"] is False and isinstance(error, dict), (name, answers)
        assert error["code"] == ErrorCode.PARAMETER, (name, error)
        assert "principal" in str(error["message"]), (name, error)
        assert all(code is None for code in alive(harness).values()), (name, alive(harness))
    for template in INVALID_KEYS:  # Zenoh refuses these before they leave the process
        with pytest.raises(zenoh.ZError):
            client.session.get(template.format(unit=client.unit_key(kind.unit, keys.CMD)[:-4]))
    sent = len(HOSTILE_CHUNKS)
    wait_until(lambda: (_bad_keys(client, kind.unit) or 0) >= before + sent, 10.0)
    samples = scrape(harness.metrics_port)  # type: ignore[attr-defined]
    assert (value(samples, "d1_agent_bad_keys_total") or 0) >= before + sent, samples
    assert send(client, kind, kind.moves()).ok  # it still serves


def test_hostile_keys_on_every_queryable_end_no_process(kinds_fleet: FleetHarness) -> None:
    """Wildcard and malformed keys over every queryable at once (each agent's, the
    coordinator's, the info queryables): every process stays up, the coordinator answers its
    own with a clear error and counts them, and the fleet still stops and serves."""
    harness = kinds_fleet
    client = harness.client()
    prefix = client.keys.prefix
    request = m.encode(m.MultiArmRequest(target="all", command=m.Hold()))
    for name, chunk in HOSTILE_CHUNKS.items():
        answers = _answers(client, f"{client.keys.prefix}/{keys.COORDINATOR_CMD}/{chunk}", request)
        assert len(answers) == 1, (name, answers)
        error = answers[0]["error"]
        assert isinstance(error, dict) and error["code"] == ErrorCode.PARAMETER, (name, error)
        for key in (f"{prefix}/*/*/cmd/{chunk}", f"{prefix}/**/cmd/{chunk}"):
            _answers(client, key, request)  # whatever answers, nobody may die
        _answers(client, f"{prefix}/**", request)
        assert all(code is None for code in alive(harness).values()), (name, alive(harness))

    def coordinator_counted() -> bool:
        diag = decode(m.CoordinatorDiag, latest(client, client.keys.coordinator_diag))
        return diag.bad_keys >= len(HOSTILE_CHUNKS)  # type: ignore[attr-defined]

    wait_until(coordinator_counted, 10.0)
    # Heartbeats on keys naming no principal: ignored, and counted by the agent.
    before = _counted_bad_keys(client, "a1")
    concrete = [c for c in HOSTILE_CHUNKS.values() if "*" not in c]
    beat = m.encode(m.Heartbeat(time.time_ns(), "hostile", 1, 0.1, {}))
    for chunk in concrete:
        put(client, f"{prefix}/{keys.HEARTBEAT}/{chunk}", beat, every_one=True)
    wait_until(lambda: (_bad_keys(client, "a1") or 0) >= before + len(concrete), 10.0)
    # The fleet still stops, and after a reset still serves, every kind.
    watches = [LatchWatch(client, kind) for kind in KINDS]
    acks = client.estop(timeout_s=5.0, wait_still=False)
    assert all(ack is not None for ack in acks.values()), acks
    client.reset()
    wait_until(lambda: all(w.estopped() is False for w in watches), 10.0)
    for kind in KINDS:
        assert send(client, kind, kind.moves()).ok, kind
    assert all(code is None for code in alive(harness).values()), alive(harness)
