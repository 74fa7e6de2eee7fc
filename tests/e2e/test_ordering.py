"""Commands run at most once and never out of order for one owner: the pure bookkeeping, then a
hostile client on a real fleet that sends duplicates, replays and stale commands."""

from __future__ import annotations

import time

import msgspec

from fleet.devices.ordering import MAX_RECENT, CommandOrder
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode
from testkit.harness import FleetHarness


def test_a_stamp_is_served_once_per_principal() -> None:
    order = CommandOrder()
    assert order.refusal("ann", None, 100) is None
    order.record("ann", None, 100)
    assert "duplicate" in (order.refusal("ann", None, 100) or "")
    assert order.refusal("bob", None, 100) is None  # another principal's stamp
    assert order.refusal("ann", None, None) is None  # unstamped: nothing to compare


def test_an_owners_commands_run_in_order() -> None:
    order = CommandOrder()
    order.record("ann", "ann/p", 200)
    assert "out of order" in (order.refusal("ann", "ann/p", 150) or "")
    assert order.refusal("ann", "ann/q", 150) is None  # another owner
    assert order.refusal("ann", "ann/p", 201) is None


def test_the_tables_are_bounded() -> None:
    order = CommandOrder()
    for stamp in range(MAX_RECENT + 10):
        order.record("ann", f"ann/{stamp}", stamp)
    assert order.refusal("ann", None, 0) is None  # forgotten (long past any lifetime)
    assert len(order._recent) == MAX_RECENT  # noqa: SLF001 - the bound is the point


def _send(h: FleetHarness, client, command: m.ArmCommand) -> m.CommandReply:  # type: ignore[no-untyped-def]
    """A raw query with exactly this payload (no client-side stamping)."""
    replies = [
        r.ok.payload.to_bytes()
        for r in client.session.get(
            client.command_key("a1"), payload=m.encode(command), timeout=5.0
        )
        if r.ok is not None
    ]
    assert replies, "no reply"
    return msgspec.json.decode(replies[0], type=m.CommandReply)


def test_duplicates_replays_and_stale_commands_never_run(fleet_harness: FleetHarness) -> None:
    h = fleet_harness
    client = h.start_fleet()
    written: list[str] = []
    sub = client.session.declare_subscriber(
        client.keys.arm("a1", "raw/command"), lambda s: written.append(s.payload.to_string())
    )
    try:
        now = time.time_ns()
        move = m.MoveJoint(joint=0, angle_deg=7.0, owner="p", stamp_ns=now, lifetime_s=5.0)
        assert _send(h, client, move).ok
        again = _send(h, client, move)  # a duplicate, or a replay within the lifetime
        assert again.error is not None and again.error.code == ErrorCode.OUT_OF_ORDER
        assert "duplicate" in again.error.message
        stale = msgspec.structs.replace(move, stamp_ns=now - 1_000_000, angle_deg=30.0)
        late = _send(h, client, stale)  # overtaken by a newer command of the same owner
        assert late.error is not None and "out of order" in late.error.message
        old = msgspec.structs.replace(move, owner="q", stamp_ns=now - 6_000_000_000)
        replay = _send(h, client, old)  # a replay past its lifetime
        assert replay.error is not None and "lifetime" in replay.error.message
        time.sleep(0.3)
    finally:
        sub.undeclare()
    moves = [text for text in written if '"funcode":1' in text]
    assert len(moves) == 1, f"the arm was sent {len(moves)} moves: {moves}"


def test_a_player_counts_an_overtaken_target_instead_of_aborting() -> None:
    """The player sends a stream's targets from a thread pool, so two of one arm's targets can
    leave out of order on a loaded host; the agent refuses the older one (the newer was taken).
    A play aborted on that ("refused a target: [3104] ... out of order"); it now counts it.
    A duplicate or an expired target still aborts."""
    from fleet.choreo.player import overtaken
    from fleet.wire.messages import ErrorCode, ErrorInfo

    order = CommandOrder()
    order.record("ann", "ann/player", 200)
    late = order.refusal("ann", "ann/player", 150)
    again = order.refusal("ann", "ann/player", 200)
    assert late is not None and again is not None
    # As edge_agent/serving.py words the refusal.
    assert overtaken(ErrorInfo(int(ErrorCode.OUT_OF_ORDER), f"arm 'a2': {late}"))
    assert not overtaken(ErrorInfo(int(ErrorCode.OUT_OF_ORDER), f"arm 'a2': {again}"))
    lifetime = "target for arm 'a2' arrived 400 ms after it was sent, past its lifetime"
    assert not overtaken(ErrorInfo(int(ErrorCode.EXPIRED), lifetime))
    assert not overtaken(ErrorInfo(int(ErrorCode.PARAMETER), f"arm 'a2': {late}"))
