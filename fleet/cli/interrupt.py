"""Ctrl-C during a command that moves arms (``fleet move --wait``, ``fleet calibrate``): the
command ends the motion it started, says what it did, and exits 130 (128 + SIGINT, as a shell
reports a command that Ctrl-C ended). Before, it exited 0 without a word and the arm went on.

The gentle end is a hold, under the command's own owner: the arm takes its measured angles as
its target and stays there, and nothing latches. A protective stop (a latch: ``fleet reset``
releases it) is the fallback for an arm whose agent did not answer the hold. An arm whose hold
was refused because another owner took it over (3207) is theirs now: it is not stopped, and
the line says so.

The command installs ``fleet.runtime.shutdown_event`` first (``bound_s=EXIT_BOUND_S``), so the
signal sets an Event and no KeyboardInterrupt lands inside a Zenoh call.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from fleet.client import FleetClient
from fleet.wire import messages as m
from fleet.wire.messages import ErrorCode

EXIT_INTERRUPTED = 130
STOP_TIMEOUT_S = 2.0
EXIT_BOUND_S = 12.0
"""From the Ctrl-C, the command exits within this (else it prints its threads' stacks and exits
1): a hold's reply (5 s at most), the fallback stop (2 s) and the session's close (2 s) fit in
it; the default 8 s did not, for an arm whose agent does not answer."""
T = TypeVar("T")


class Interrupted(Exception):
    """Ctrl-C (or SIGTERM) came while a command was waiting."""


def until_interrupted(work: Callable[[], T], stop: threading.Event) -> T:
    """``work()`` on a daemon thread, its result; Interrupted when ``stop`` is set first. The
    thread is left behind, waiting on its query until the client's session closes: a daemon,
    so it never holds the process's exit."""
    outcome: list[T] = []
    failure: list[BaseException] = []

    def run() -> None:
        try:
            outcome.append(work())
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            failure.append(exc)

    thread = threading.Thread(target=run, name="command", daemon=True)
    thread.start()
    while thread.is_alive():
        if stop.wait(0.02):
            raise Interrupted
    if failure:
        raise failure[0]
    return outcome[0]


def hold_what_moved(
    client: FleetClient, arms: list[str], owner: str | None, what: str, sync_target: str = ""
) -> int:
    """Hold each of ``arms`` where it stands (a protective stop where the hold got no answer)
    and print one line per arm; returns EXIT_INTERRUPTED. ``sync_target``: the arms moved
    through the coordinator (``--sync``), which holds them as it moved them, as their owner."""
    where = "where it stands" if len(arms) == 1 else "where they stand"
    print(f"{what}: interrupted; holding {', '.join(arms)} {where}", flush=True)
    if sync_target:
        multi = client.multi(sync_target, m.Hold(), sync=False, partial=True)
        replies = [multi.replies.get(arm, _unanswered(arm, multi.error)) for arm in arms]
    else:
        with ThreadPoolExecutor(max_workers=min(16, len(arms))) as pool:
            replies = list(pool.map(lambda arm: client.command(arm, m.Hold(owner=owner)), arms))
    for arm, reply in zip(arms, replies):
        print(_held_or_stopped(client, arm, reply, what), flush=True)
    return EXIT_INTERRUPTED


def _unanswered(arm: str, error: m.ErrorInfo | None) -> m.CommandReply:
    """The reply of an arm the coordinator did not answer for."""
    error = error or m.ErrorInfo(int(ErrorCode.NO_AGENT), "the coordinator did not answer")
    return m.CommandReply(False, arm, None, False, None, None, 0.0, error)


def _held_or_stopped(client: FleetClient, arm: str, reply: m.CommandReply, what: str) -> str:
    if reply.ok:
        return f"{arm}: held (its move was cut short)"
    error = reply.error
    why = f"[{error.code}] {error.message}" if error is not None else "no reply"
    if error is not None and error.code == ErrorCode.LEASE_EXISTS:
        return f"{arm}: NOT held, another owner commands it now: {why}"
    reason = f"{what} interrupted; its hold failed: {why}"
    acks = client.estop(arm, reason=reason, timeout_s=STOP_TIMEOUT_S)
    if acks.get(arm) is not None:
        return (
            f"{arm}: its hold failed ({why}); protective stop acknowledged "
            f"(`fleet reset {arm}` releases it)"
        )
    return (
        f"{arm}: NOT stopped: its hold failed ({why}) and no agent acknowledged the protective "
        "stop; use the arm's hardware stop if it still moves"
    )
