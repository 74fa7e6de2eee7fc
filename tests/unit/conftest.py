"""The unit folder's rule, enforced: a test here starts no process and opens no network
(no IP socket, no Zenoh session, no DDS participant, no viser server). A test that needs one
belongs in tests/e2e; the guard fails it with the reason instead of letting the fast folder
slow down or flake."""

from __future__ import annotations

import multiprocessing.process
import socket
import subprocess
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh
from cyclonedds.domain import DomainParticipant

IP_FAMILIES = (socket.AF_INET, socket.AF_INET6)


def _refuse(what: str) -> Callable[..., Any]:
    def refuse(*_args: Any, **_kwargs: Any) -> Any:
        raise AssertionError(f"a unit test {what}: move it to tests/e2e (tests/README.md)")

    return refuse


def _ip_only(original: Callable[..., Any], what: str) -> Callable[..., Any]:
    def guarded(sock: socket.socket, *args: Any) -> Any:
        if sock.family in IP_FAMILIES:
            _refuse(what)()
        return original(sock, *args)

    return guarded


@pytest.fixture(autouse=True)
def no_processes_no_network(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Refuse what makes a test slow or flaky: processes, IP sockets, Zenoh, DDS."""
    monkeypatch.setattr(subprocess.Popen, "__init__", _refuse("started a process"))
    monkeypatch.setattr(multiprocessing.process.BaseProcess, "start", _refuse("started a process"))
    monkeypatch.setattr(socket.socket, "bind", _ip_only(socket.socket.bind, "bound a socket"))
    monkeypatch.setattr(socket.socket, "connect", _ip_only(socket.socket.connect, "connected"))
    monkeypatch.setattr(zenoh, "open", _refuse("opened a Zenoh session"))
    monkeypatch.setattr(DomainParticipant, "__init__", _refuse("created a DDS participant"))
    yield
