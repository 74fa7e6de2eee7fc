"""``fleet demo``'s free-port check: a port whose last connections linger in TIME-WAIT is free."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from fleet.cli.processes import _port_free


def test_a_port_in_time_wait_is_free_to_listen_on() -> None:
    with socket.socket() as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        client = socket.create_connection(("127.0.0.1", port))
        accepted, _ = server.accept()
        accepted.close()  # the server side closes first: its end goes to TIME-WAIT
        client.close()
    endpoint = f"tcp/127.0.0.1:{port}"
    assert _port_free(endpoint), "a port in TIME-WAIT was reported in use"
    with socket.socket() as listener:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the router does
        listener.bind(("127.0.0.1", port))
        listener.listen()
        assert not _port_free(endpoint), "a port with a listener was reported free"


@pytest.mark.parametrize("command", ["router", "foxglove"])
def test_a_busy_port_is_one_line_not_a_traceback(command: str) -> None:
    """``fleet router --endpoint`` and ``fleet foxglove --port`` on a taken port printed a
    Python traceback; now one line naming the port and the fix, exit code 3."""
    with socket.socket() as listener:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = listener.getsockname()[1]
        if command == "router":
            argv = ["router", "--endpoint", f"tcp/127.0.0.1:{port}"]
        else:  # its router is nowhere: the port check comes first
            argv = ["foxglove", "--port", str(port), "--endpoint", "tcp/127.0.0.1:1"]
        run = subprocess.run(
            [sys.executable, "-m", "fleet.cli.main", *argv],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert run.returncode == 3, run.stderr
    assert "Traceback" not in run.stderr, run.stderr
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and f"{port}" in lines[0] and "in use" in lines[0], run.stderr
