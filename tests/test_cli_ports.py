"""``fleet demo``'s free-port check: a port whose last connections linger in TIME-WAIT is free."""

from __future__ import annotations

import socket

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
