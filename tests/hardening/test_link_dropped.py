"""A peer that accepts the connection and drops it (a serial-over-TCP bridge that resets, a wrong service on the
port) during the ARCOS handshake (session 25, C): a lost link, one line, exit 1. Before, pyserial's SerialException
('read failed: socket disconnected') reached the command as 'internal error: SerialException: ...'."""
from __future__ import annotations

import socket
import struct
import threading

import pytest

from tests.datasets.conftest import run_cli


@pytest.fixture
def dropping_peer():
    """socket://127.0.0.1:PORT of a listener that resets every connection it accepts once the first byte came."""
    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.settimeout(5)
            try:
                conn.recv(1)   # the driver's first SYNC0: the handshake is under way
            except OSError:
                pass
            conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close with a reset
            conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"socket://127.0.0.1:{server.getsockname()[1]}"
    stop.set()
    server.shutdown(socket.SHUT_RDWR)   # wakes the accept() the thread waits in (close alone does not, on Linux)
    server.close()
    thread.join(timeout=5)
    assert not thread.is_alive()


@pytest.mark.parametrize("argv", [["robot", "info"], ["robot", "drive", "--seconds", "1"]], ids=" ".join)
def test_a_dropped_connection_is_a_lost_link_in_one_line(dropping_peer, argv) -> None:
    status, _, err = run_cli(*argv, dropping_peer, "--link-timeout", "1")
    assert status == 1 and err.count("\n") == 1, err
    assert "internal error" not in err and "SerialException" not in err and f"{dropping_peer}: link dropped" in err, err
