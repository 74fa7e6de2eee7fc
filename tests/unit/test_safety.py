"""The agent's pure safety logic (fleet/devices/safety.py) with an injected clock: the stop latch,
standstill, the lease and the watchdog. The bugs of earlier rounds lived here: a repeat that
re-latched after a reset, a watchdog that tripped before the commander was ever heard, a lease
that outlived a stop."""

from __future__ import annotations

import pytest

from fleet.d1.standstill import STILL_SAMPLES, STILL_TOLERANCE_DEG
from fleet.devices.safety import (
    RESET_IDS_KEPT,
    STOP_CAUSES_KEPT,
    STOP_REASON_CHARS,
    STOP_REPEAT_S,
    SUPERSEDED_IDS_KEPT,
    ArmSafety,
    LeaseRefused,
)

HOME = (0.0,) * 7
LEASE_S, WATCHDOG_S = 3.0, 0.5


def _safety() -> ArmSafety:
    return ArmSafety(lease_s=LEASE_S, watchdog_s=WATCHDOG_S)


def _latch(safety: ArmSafety, stop_id: str, now_s: float = 0.0, action: str = "hold") -> bool:
    return safety.latch(stop_id, "fleet", "test", now_s, int(now_s * 1e9), action)


def _still(safety: ArmSafety, now_s: float, pose: tuple[float, ...] = HOME) -> bool:
    """Feed STILL_SAMPLES identical reports from ``now_s`` on; True if one confirmed a stop."""
    confirmed = False
    for k in range(STILL_SAMPLES):
        t = now_s + 0.1 * k
        confirmed |= safety.on_angles(pose, int(t * 1e9), t)
    return confirmed


# ----------------------------------------------------------------------------- latch


def test_a_stop_latches_once_and_its_repeats_do_not_relatch() -> None:
    safety = _safety()
    assert not safety.latched
    assert _latch(safety, "s1")
    assert safety.latched and safety.is_current("s1")
    assert not _latch(safety, "s1", 0.5), "a repeat is not a new stop"
    assert safety.stop is not None and safety.stop.received_s == 0.0
    assert "stopped by fleet" in (safety.last_reason or "")


def test_a_reset_releases_the_stop_and_its_repeats_never_latch_again() -> None:
    safety = _safety()
    _latch(safety, "s1")
    released = safety.reset()
    assert released is not None and released.stop_id == "s1"
    assert not safety.latched
    assert not _latch(safety, "s1", 1.0), "a heartbeat repeating a reset stop re-latched"
    assert _latch(safety, "s2", 1.0), "a new stop must latch"
    assert safety.reset() is not None and safety.reset() is None


T0 = 1_800_000_000 * 10**9
"""A receiver's wall clock (ns) in the tests below."""
MS = 10**6


def _stop_at(safety: ArmSafety, stop_id: str, stamp_ns: int, arrival_ns: int) -> bool:
    return safety.latch(stop_id, "op", "", arrival_ns / 1e9, arrival_ns, stamp_ns=stamp_ns)


def test_a_late_datagram_copy_of_a_reset_stop_never_latches_again() -> None:
    """A stop's copies come on two paths and a burst; any copy arriving after the
    reset (the UDP copy behind, or a replay of it) is a repeat of a reset stop."""
    safety = _safety()
    assert _stop_at(safety, "s1", T0, T0 + 1 * MS)
    assert not _stop_at(safety, "s1", T0, T0 + 2 * MS), "a duplicate acted on"
    assert safety.reset(stamp_ns=T0 + 5 * MS, now_ns=T0 + 6 * MS) is not None
    for k in range(30):  # the rest of the burst, the reliable copy, a replay minutes later
        assert not _stop_at(safety, "s1", T0, T0 + (10 + k * 1000) * MS)
    assert not safety.latched


def test_a_reset_put_before_a_stop_does_not_release_it() -> None:
    """A stop's datagram copy can overtake a reset still on its way over TCP; that
    older reset must neither release the newer stop nor make its own reliable copy a repeat."""
    safety = _safety()
    assert _stop_at(safety, "s2", T0 + 20 * MS, T0 + 21 * MS)
    outcome = safety.answer_reset(T0 + 10 * MS, T0 + 300 * MS)  # put first, arrived later
    assert outcome.outcome == "kept" and outcome.released is None, outcome
    assert "reset again" in outcome.detail
    assert safety.latched and safety.is_current("s2")
    assert not _stop_at(safety, "s2", T0 + 20 * MS, T0 + 400 * MS)  # its copy: a repeat
    assert safety.answer_reset(T0 + 500 * MS, T0 + 501 * MS).outcome == "released"
    assert not safety.latched
    assert safety.answer_reset(T0 + 600 * MS, T0 + 601 * MS).outcome == "not_stopped"


def test_an_older_stop_arriving_after_a_newer_one_does_not_let_a_reset_release_the_newer() -> None:
    """Copies on two paths: the newer stop s3 arrives first, then the older s1 (it becomes the
    latched one), then a reset put between them: the reset is older than s3, so nothing is
    released, and s3's own later copy finds it still latched."""
    safety = _safety()
    assert _stop_at(safety, "s3", T0 + 30 * MS, T0 + 31 * MS)
    assert _stop_at(safety, "s1", T0 + 10 * MS, T0 + 40 * MS)  # supersedes on arrival
    assert safety.reset(stamp_ns=T0 + 20 * MS, now_ns=T0 + 50 * MS) is None
    assert safety.latched
    assert safety.reset(stamp_ns=T0 + 60 * MS, now_ns=T0 + 61 * MS) is not None
    assert not safety.latched


@pytest.mark.parametrize(
    "stamp_ns",
    [0, T0 - 5 * 10**9, T0 - 3600 * 10**9, T0 + 30 * 10**9, 2**63 - 1],
    ids=["zero", "5s-behind", "1h-behind", "30s-ahead", "max"],
)
def test_no_stamp_makes_a_stop_ignored_and_every_stop_can_be_reset(stamp_ns: int) -> None:
    """A stop latches whatever its stamp, after resets of any stamp; a reset with a sane
    stamp put after it releases it (a stop from a clock far ahead included)."""
    safety = _safety()
    assert _stop_at(safety, "first", T0, T0 + 1 * MS)
    assert safety.answer_reset(T0 + 1_500 * MS, T0 + 2_000 * MS).outcome == "released"
    assert _stop_at(safety, "odd", stamp_ns, T0 + 3_000 * MS), "a stop dropped for its stamp"
    assert safety.latched
    assert safety.answer_reset(T0 + 4_000 * MS, T0 + 4_001 * MS).outcome == "released"


@pytest.mark.parametrize("ahead_s", [2.5, 30.0, (2**63 - 1 - T0) / 1e9], ids=["2.5s", "30s", "max"])
def test_a_reset_stamped_far_ahead_is_refused_and_later_stops_still_latch(ahead_s: float) -> None:
    safety = _safety()
    assert _stop_at(safety, "s1", T0, T0 + 1 * MS)
    bad = min(2**63 - 1, T0 + int(ahead_s * 1e9))
    outcome = safety.answer_reset(bad, T0 + 2 * MS)
    assert outcome.outcome == "refused" and "ahead of this agent's clock" in outcome.detail
    assert safety.latched
    assert safety.answer_reset(T0 + 3 * MS, T0 + 4 * MS).outcome == "released"
    for k in range(3):  # the CLI's, the heartbeat's, the watchdog's (no stamp)
        assert _stop_at(safety, f"later{k}", T0 + (10 + k) * MS, T0 + (11 + k) * MS)
        assert safety.answer_reset(T0 + (20 + k) * MS, T0 + (21 + k) * MS).released
    assert safety.latch("watchdog-1", "watchdog", "", 1.0, T0 + 30 * MS)


def test_a_reset_from_a_clock_slightly_ahead_does_not_outlast_its_arrival() -> None:
    """A reset 1.5 s ahead (accepted) is ordered at its arrival: a stop put 10 ms later
    latches and a reset after that releases it."""
    safety = _safety()
    assert _stop_at(safety, "s1", T0, T0 + 1 * MS)
    assert safety.answer_reset(T0 + 1_500 * MS, T0 + 2 * MS).outcome == "released"
    assert _stop_at(safety, "s2", T0 + 12 * MS, T0 + 13 * MS)
    assert safety.answer_reset(T0 + 20 * MS, T0 + 21 * MS).outcome == "released"


def test_a_reset_from_a_clock_behind_says_so_when_it_keeps_a_stop() -> None:
    safety = _safety()
    assert _stop_at(safety, "s1", T0, T0 + 1 * MS)
    outcome = safety.answer_reset(T0 + 1_000 * MS - 2 * 10**9, T0 + 1_000 * MS)
    assert outcome.outcome == "kept" and "behind this agent's clock" in outcome.detail
    assert safety.answer_reset(T0 + 4_000 * MS - 2 * 10**9, T0 + 4_000 * MS).released


def test_the_agents_own_stops_are_released_by_any_reset() -> None:
    safety = _safety()
    assert safety.latch("watchdog-1", "watchdog", "", 0.0, T0)  # no sender stamp
    assert safety.reset(stamp_ns=1, now_ns=T0) is not None


def test_a_newer_stop_supersedes_and_one_reset_releases_both() -> None:
    safety = _safety()
    _latch(safety, "s1")
    assert _latch(safety, "s2", 0.1)
    assert safety.is_current("s2")
    assert not _latch(safety, "s1", 0.2), "the superseded stop's repeat latched again"
    safety.reset()
    assert not _latch(safety, "s1", 0.3) and not _latch(safety, "s2", 0.3)


def test_every_active_stops_who_and_why_is_kept_until_the_reset() -> None:
    """Issue 26 item 9: ``fleet estop --reason test`` then a plain stop kept only the second."""
    safety = _safety()
    assert safety.latch("s1", "cli@pc", "test", 0.0, 0)
    assert safety.latch("s2", "viewer", "", 0.1, 1)
    assert safety.last_reason == "stopped by cli@pc: test; then by viewer"
    safety.note_also_stopped_by("s3", "coordinator", "contact on a2")  # a heartbeat's repeat
    safety.note_also_stopped_by("s4", "viewer", "")  # same who and why: said once
    assert safety.last_reason == (
        "stopped by cli@pc: test; then by viewer; then by coordinator: contact on a2"
    )
    safety.reset()
    assert safety.latch("s5", "viewer", "", 1.0, 2)
    assert safety.last_reason == "stopped by viewer", "a reset forgets the released stops"


def test_the_stop_causes_are_bounded() -> None:
    safety = _safety()
    for k in range(STOP_CAUSES_KEPT + 5):
        safety.latch(f"s{k}", f"who{k}", "x" * 500, k * 0.01, k)
    reason = safety.last_reason or ""
    assert len(safety.causes) == STOP_CAUSES_KEPT and len(reason) <= STOP_REASON_CHARS
    assert reason.startswith("stopped by who0: ") and reason.endswith("...")
    safety.reset()
    for k in range(STOP_CAUSES_KEPT + 5):
        safety.latch(f"t{k}", f"w{k}", "", k * 0.01, k)
    assert (safety.last_reason or "").endswith("then by w7; and 5 more")


def test_the_memory_of_stop_ids_is_bounded() -> None:
    safety = _safety()
    for k in range(SUPERSEDED_IDS_KEPT * 3):
        _latch(safety, f"flood-{k}", k * 0.001)
    assert len(safety.superseded_ids) <= SUPERSEDED_IDS_KEPT
    for k in range(RESET_IDS_KEPT * 2):
        _latch(safety, f"r-{k}")
        safety.reset()
    assert len(safety.reset_stop_ids) <= RESET_IDS_KEPT


def test_a_stop_ends_the_lease_and_the_watch() -> None:
    safety = _safety()
    safety.check_owner("operator/a", takeover=False, now_s=0.0)
    safety.watch("coordinator/c", 0.0)
    _latch(safety, "s1", 0.1)
    assert safety.lease is None and safety.watched_by is None
    safety.check_owner("operator/b", takeover=False, now_s=0.2)  # no LeaseRefused


# ----------------------------------------------------------------------------- standstill


def test_a_hold_stop_is_confirmed_by_standstill_and_repeated_until_then() -> None:
    safety = _safety()
    _latch(safety, "s1")
    assert safety.stop is not None
    safety.stop.last_sent_s = 0.0
    assert not safety.needs_resend(STOP_REPEAT_S / 2)
    assert safety.needs_resend(STOP_REPEAT_S)
    moving = [(float(k),) * 7 for k in range(STILL_SAMPLES)]
    for k, pose in enumerate(moving):
        assert not safety.on_angles(pose, k, 0.1 * k)
    assert _still(safety, 1.0)
    assert safety.stop.done and safety.stop.still_ns is not None
    assert not safety.needs_resend(10.0)
    assert not _still(safety, 2.0), "confirmed twice"


def test_a_stop_is_still_from_the_first_report_the_confirming_ones_agree_with() -> None:
    """The stop's ``still_ns`` is when the arm stopped moving (the first report of the still
    window), not when the last report confirmed it: the row's "put -> still" is the arm's, the
    ack carries both (it is sent at the confirmation)."""
    safety = _safety()
    _latch(safety, "s1", now_s=0.0)  # received at 0 ns
    ms = 1_000_000
    decelerating = [(10.0,) * 7, (14.0,) * 7, (15.0,) * 7]
    still = [(15.1,) * 7, (15.1,) * 7]
    reports = [*decelerating, *still]
    confirmed = [
        safety.on_angles(pose, (k + 1) * 100 * ms, 0.1 * (k + 1)) for k, pose in enumerate(reports)
    ]
    assert confirmed == [False, False, False, False, True]
    assert safety.stop is not None
    assert safety.stop.still_ns == 300 * ms, "still from the third report (15.0) on"


def test_an_arm_still_already_is_still_from_the_stops_write_never_before() -> None:
    safety = _safety()
    safety.on_angles((0.0,) * 7, 0, 0.0)  # before the stop: the latch clears the window
    _latch(safety, "s1", now_s=1.0)
    assert safety.stop is not None
    safety.stop.dds_written_ns = int(1.05e9)
    for k in range(STILL_SAMPLES):
        safety.on_angles((0.0,) * 7, int((1.0 + 0.01 * k) * 1e9), 1.0 + 0.01 * k)
    assert safety.stop.still_ns == int(1.05e9)


def test_standstill_tolerates_noise_below_the_tolerance_only() -> None:
    safety = _safety()
    _latch(safety, "s1")
    noisy = [(0.0,) * 7, (STILL_TOLERANCE_DEG * 0.9,) * 7, (0.0,) * 7]
    assert any(safety.on_angles(pose, k, 0.1 * k) for k, pose in enumerate(noisy))
    safety = _safety()
    _latch(safety, "s1")
    drifting = [(0.0,) * 7, (0.0,) * 7, (STILL_TOLERANCE_DEG * 1.5,) * 7]
    assert not any(safety.on_angles(pose, k, 0.1 * k) for k, pose in enumerate(drifting))


@pytest.mark.parametrize(
    ("action", "status"),
    [
        ("unload", {"enabled": False, "powered": True}),
        ("power_off", {"enabled": True, "powered": False}),
    ],
)
def test_unload_and_power_off_are_done_only_when_still_and_confirmed_by_status(
    action: str, status: dict[str, bool]
) -> None:
    safety = _safety()
    _latch(safety, "s1", action=action)
    _still(safety, 0.0)
    assert safety.stop is not None and not safety.stop.done
    assert not safety.on_status(enabled=True, powered=True, now_ns=1)
    assert safety.on_status(now_ns=2, **status)
    assert safety.stop.done and safety.stop.confirmed_ns == 2
    assert not safety.on_status(now_ns=3, **status), "confirmed twice"


# ----------------------------------------------------------------------------- lease


def test_one_owner_at_a_time_until_its_lease_expires() -> None:
    safety = _safety()
    safety.check_owner("operator/a", takeover=False, now_s=0.0)
    with pytest.raises(LeaseRefused) as refused:
        safety.check_owner("operator/b", takeover=False, now_s=1.0)
    assert refused.value.holder == "operator/a"
    safety.check_owner("operator/a", takeover=False, now_s=2.0)  # renews to 5.0
    with pytest.raises(LeaseRefused):
        safety.check_owner("operator/b", takeover=False, now_s=4.9)
    safety.check_owner("operator/b", takeover=False, now_s=5.1)
    assert safety.lease is not None and safety.lease.owner == "operator/b"


def test_the_holder_and_since_when_are_kept_across_renewals() -> None:
    """The viewer shows who holds an arm and for how long (issue 15): a renewal keeps the
    start, a new owner starts again, an expired lease holds nothing."""
    safety = _safety()
    assert safety.holder(0.0) is None
    safety.check_owner("operator/a", takeover=False, now_s=10.0)
    safety.check_owner("operator/a", takeover=False, now_s=12.0)
    lease = safety.holder(12.5)
    assert lease is not None and lease.owner == "operator/a"
    assert lease.since_s == 10.0 and lease.expires_s == 12.0 + LEASE_S
    safety.check_owner("operator/b", takeover=True, now_s=13.0)
    lease = safety.holder(13.0)
    assert lease is not None and lease.owner == "operator/b" and lease.since_s == 13.0
    assert safety.holder(13.0 + LEASE_S + 0.1) is None


def test_a_takeover_takes_the_lease_and_a_release_frees_it() -> None:
    safety = _safety()
    safety.check_owner("operator/a", takeover=False, now_s=0.0)
    safety.check_owner("operator/b", takeover=True, now_s=0.1)
    assert safety.lease is not None and safety.lease.owner == "operator/b"
    assert not safety.release("operator/a"), "a former owner released someone else's lease"
    assert safety.release("operator/b")
    safety.check_owner("operator/a", takeover=False, now_s=0.2)


# ----------------------------------------------------------------------------- watchdog


def test_the_watchdog_trips_only_on_a_watched_arm_after_the_silence() -> None:
    safety = _safety()
    assert not safety.watchdog_expired(None, 100.0), "an unwatched arm tripped"
    safety.check_owner("coordinator/c", takeover=False, now_s=10.0)
    safety.watch("coordinator/c", 10.0)
    assert not safety.watchdog_expired(None, 10.0 + WATCHDOG_S * 0.9)
    assert safety.watchdog_expired(None, 10.0 + WATCHDOG_S * 1.1), "the watch start is a beat"
    assert not safety.watchdog_expired(10.4, 10.4 + WATCHDOG_S * 0.9)
    assert safety.watchdog_expired(10.4, 10.4 + WATCHDOG_S * 1.1)
    _latch(safety, "watchdog-a1", 11.0)
    assert not safety.watchdog_expired(10.4, 20.0), "a latched arm needs no second stop"


def test_the_watch_ends_when_the_owner_finished_or_another_commands() -> None:
    safety = _safety()
    safety.check_owner("coordinator/c", takeover=False, now_s=0.0)
    safety.watch("coordinator/c", 0.0)
    _still(safety, 0.1)  # still, but the owner's lease is fresh: a pause, not the end
    assert safety.watched_by == "coordinator/c"
    _still(safety, LEASE_S + 0.5)  # still and the owner silent for its lease: it finished
    assert safety.watched_by is None
    safety.check_owner("coordinator/c", takeover=False, now_s=10.0)
    safety.watch("coordinator/c", 10.0)
    safety.check_owner("operator/o", takeover=True, now_s=10.1)
    assert safety.watched_by is None, "another commander's arm is not the first one's to hold"
    safety.check_owner("coordinator/c", takeover=True, now_s=11.0)
    safety.watch("coordinator/c", 11.0)
    assert safety.release("coordinator/c") and safety.watched_by is None
