"""runtime/rerun_watch.ViewerWatch sees this process's own connection to a viewer's port, not the machine's.

The viewer here is a plain TCP listener in the test process; this process's connection to it stands for Rerun's gRPC
client (the watch looks at the process's sockets, whichever thread opened them). A second process holds a
connection to the same port, as another mission streaming to the same viewer does. Session 48's watch read the
network namespace's TCP table, where that other connection kept the port looking alive: a viewer that dropped this
process's stream was never said. The bounds are failure bounds, not measurements.
"""
from __future__ import annotations

import socket
import subprocess
import sys
import time

import pytest

from runtime import rerun_watch
from runtime.rerun_watch import ViewerWatch

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the watch reads /proc (Linux)")

BOUND = 60.0   # s: a condition not met by then is not going to be
_HOLDER = ("import socket, sys\n"
           "held = socket.create_connection(('127.0.0.1', int(sys.argv[1])))\n"
           "print('connected', flush=True)\n"
           "sys.stdin.read()\n")   # holds the connection until the test closes its stdin


def _wait_until(condition) -> bool:
    deadline = time.monotonic() + BOUND
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


@pytest.fixture
def viewer():
    with socket.create_server(("127.0.0.1", 0)) as server:
        server.settimeout(BOUND)
        yield server


def test_a_dropped_connection_is_said_though_another_process_streams_to_the_same_port(viewer, monkeypatch):
    monkeypatch.setattr(rerun_watch, "VIEWER_LOOK_INTERVAL", 0.02)
    port = viewer.getsockname()[1]
    ours = socket.create_connection(("127.0.0.1", port))
    theirs_holder = None
    watch = ViewerWatch(f"rerun+http://127.0.0.1:{port}/proxy", port)
    try:
        our_end, _ = viewer.accept()
        assert _wait_until(lambda: watch.connected), "our connection was never seen"
        theirs_holder = subprocess.Popen([sys.executable, "-c", _HOLDER, str(port)], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, text=True)
        their_end, _ = viewer.accept()   # the other process's connection is established
        assert theirs_holder.stdout.readline().strip() == "connected"
        assert watch.failure() is None
        our_end.close()   # the viewer drops this process's stream; the other process's stays
        assert _wait_until(lambda: watch.failure() is not None), "the dropped connection was never said"
        assert watch.failure() == "the viewer closed the connection"
        their_end.close()
    finally:
        watch.close()
        ours.close()
        if theirs_holder is not None:
            theirs_holder.stdin.close()
            theirs_holder.wait(timeout=BOUND)
