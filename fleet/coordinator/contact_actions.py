"""Carry out contact-policy actions on the key space (runs on the coordinator's pool threads,
never on a Zenoh callback thread, never under the coordinator's lock)."""

from __future__ import annotations

import logging

from fleet.client import FleetClient
from fleet.coordinator.contact_policy import Action
from fleet.wire import messages as m

log = logging.getLogger("fleet.coordinator.contact")

BACKOFF_TIMEOUT_S = 3.0


def perform(client: FleetClient, owner: str, action: Action) -> None:
    """Do ``action``: a protective stop of the arm, a hold, a back-off and one retry, or a
    report (the log and the fleet contact table)."""
    arm = action.arm
    if action.kind == "estop":
        request = client.stop_request(reason=action.reason, source=f"{owner} (contact)")
        client.put_stop(request, arm)
        log.warning("arm %s stopped: %s", arm, action.reason)
    elif action.kind == "hold":
        reply = client.command(arm, _safety_hold(owner))
        log.warning("arm %s held (%s): %s", arm, "ok" if reply.ok else reply.error, action.reason)
    elif action.kind == "backoff_retry":
        _backoff_retry(client, owner, action)
    else:
        log.info("arm %s: %s", arm, action.reason)


def _safety_hold(owner: str) -> m.Hold:
    """A hold is subject to the arm's lease like any command: the contact policy's hold takes
    the arm from whoever moved it into the contact (their next command is refused 3207)."""
    return m.Hold(owner=owner, takeover=True)


def _backoff_retry(client: FleetClient, owner: str, action: Action) -> None:
    assert action.backoff_deg is not None and action.retry_deg is not None
    arm, joint = action.arm, action.joint
    log.warning("arm %s: %s", arm, action.reason)
    back = m.MoveJoint(
        joint=joint,
        angle_deg=action.backoff_deg,
        wait_reached=True,
        timeout_s=BACKOFF_TIMEOUT_S,
        owner=owner,
    )
    reply = client.command(arm, back)
    if not reply.ok:
        log.warning("arm %s: back-off failed (%s); holding", arm, reply.error)
        client.command(arm, _safety_hold(owner))
        return
    retry = client.command(arm, m.MoveJoint(joint=joint, angle_deg=action.retry_deg, owner=owner))
    log.info("arm %s: retried joint %d -> %s (%s)", arm, joint, action.retry_deg, retry.ok)
