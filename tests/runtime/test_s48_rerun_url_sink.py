"""``--rerun rerun+http://HOST:PORT/proxy`` where no viewer takes the stream: refused before the run, or said in one
line and the run ends (session 48, W2; coord-D item 5).

Rerun 0.41's gRPC sink, given a URL where nothing listens, retries for ever and a flush without a timeout never
returns: ``p3at run --rerun rerun+http://127.0.0.1:9899/proxy`` wrote its maps, then waited in the recording's close
for ever, and SIGTERM could not end it (its handler never ran; only SIGKILL did). A viewer that went away mid-run
failed the run (exit 1, 'the recording stage failed ... gRPC connection severed') though every file was written.

The viewers here are plain TCP listeners in the test process: one that accepts and closes each connection (a viewer
that went away), one that accepts and never answers (something that is not a Rerun viewer, or a viewer that hangs).
The subprocess timeouts are failure bounds, not measurements.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
BOUND = 240   # s: a run that has not ended by then hangs (a run takes a few seconds; the last flush at most 5 more)


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")


def _run(args: list[str], out: Path) -> list[str]:
    return [sys.executable, "-m", "runtime.cli", "run", *args, "--camera", "synthetic", "--particles", "20",
            "--quiet", "--out", str(out)]


class _Listener:
    """A TCP listener on a free loopback port: ``close`` closes each connection it accepts, ``hold`` keeps it open
    and never answers. ``spoken``: a client sent bytes on a held connection (Rerun's gRPC client; the checks of the
    URL before a run connect and close without a byte)."""

    def __init__(self, mode: str) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.url = f"rerun+http://127.0.0.1:{self.port}/proxy"
        self.mode = mode
        self.accepted = threading.Event()
        self.spoken = threading.Event()
        self.held: list[socket.socket] = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                connection, _ = self.server.accept()
            except OSError:   # closed
                return
            if self.mode == "close":
                connection.close()
            else:
                self.held.append(connection)
                threading.Thread(target=self._listen, args=(connection,), daemon=True).start()
            self.accepted.set()

    def _listen(self, connection: socket.socket) -> None:
        try:
            if connection.recv(1, socket.MSG_PEEK):
                self.spoken.set()
        except OSError:
            pass

    def close(self) -> None:
        self.server.close()
        for connection in self.held:
            connection.close()


@pytest.fixture
def listener(request):
    served = _Listener(request.param)
    yield served
    served.close()


def _closed_port() -> int:
    with socket.create_server(("127.0.0.1", 0)) as probe:
        return probe.getsockname()[1]


# runtime.commands.options.rerun_sink_problem asks runtime.rerun_sink.viewer_url_problem before anything runs
@pytest.mark.timeout(BOUND + 60)
@pytest.mark.parametrize("command", ["run", "demo"])
def test_a_url_where_no_viewer_listens_is_refused_in_one_line_before_anything(tmp_path, command):
    url = f"rerun+http://127.0.0.1:{_closed_port()}/proxy"
    out = tmp_path / "out"
    args = [sys.executable, "-m", "runtime.cli", command, "--rerun", url, "--seconds", "3", "--out", str(out)]
    if command == "run":
        args += ["--camera", "synthetic", "--quiet"]
    done = subprocess.run(args, cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=BOUND)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr   # one line, no traceback, and none of Rerun's ERROR lines
    assert url in lines[0] and "no Rerun viewer listens" in lines[0] and "connection refused" in lines[0], lines
    assert "--rerun file" in lines[0]   # what to do instead
    assert done.returncode == 2, done.stderr
    assert not out.exists()   # refused before the run: no output folder


@pytest.mark.timeout(BOUND + 60)
def test_fuse_live_refuses_a_url_where_no_viewer_listens(tmp_path):
    url = f"rerun+http://127.0.0.1:{_closed_port()}/proxy"
    done = subprocess.run([sys.executable, "-m", "runtime.cli", "fuse", "--live", "--rerun", url, "--out",
                           str(tmp_path / "fused.npz")], cwd=tmp_path, env=_env(), capture_output=True, text=True,
                          timeout=BOUND)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"p3at fuse: --rerun {url}: no Rerun viewer listens at 127.0.0.1:{url.split(':')[2].split('/')[0]} "
        "(connection refused); start one with `rerun` (it listens on 9876), or give --rerun file"]


@pytest.mark.timeout(BOUND + 60)
@pytest.mark.parametrize(("listener", "why"), [("close", "gRPC connection severed"),
                                               ("hold", "nothing took its last rows within 5 s")],
                         indirect=["listener"])
def test_a_viewer_that_goes_away_or_never_answers_is_said_and_the_run_ends(tmp_path, listener, why):
    out = tmp_path / "run"
    done = subprocess.run(_run(["--rerun", listener.url, "--seconds", "3"], out), cwd=tmp_path, env=_env(),
                          capture_output=True, text=True, timeout=BOUND)   # before: 'hold' never ended
    assert listener.accepted.is_set()   # the URL passed the check before the run
    assert listener.mode == "close" or listener.spoken.is_set()   # and Rerun's client connected
    said = [line for line in done.stderr.splitlines() if f"the live view at {listener.url} is lost" in line]
    assert len(said) == 1, done.stderr
    assert said[0].startswith("p3at run: warning: ") and why in said[0] and "the mission goes on" in said[0], said
    assert done.returncode == 0, done.stderr   # before ('close'): exit 1, 'the recording stage failed'
    assert "FAILED" not in done.stdout
    for name in ("robot1.npz", "robot1.tum"):
        assert (out / name).stat().st_size > 0


@pytest.mark.timeout(BOUND + 60)
@pytest.mark.parametrize("listener", ["hold"], indirect=True)
def test_sigterm_ends_a_run_whose_viewer_never_answers(tmp_path, listener):
    out = tmp_path / "run"
    run = subprocess.Popen(_run(["--rerun", listener.url, "--realtime", "--seconds", "600"], out), cwd=tmp_path,
                           env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Rerun's client spoke: the mission opened its recording, its stop signals are installed
        assert listener.spoken.wait(BOUND), "the run never connected"
        run.send_signal(signal.SIGTERM)
        stdout, stderr = run.communicate(timeout=BOUND)   # before: the flush in close never returned
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0, stderr   # ends as a finished run does
    assert sum(f"the live view at {listener.url} is lost" in line for line in stderr.splitlines()) == 1, stderr
    assert (out / "robot1.npz").stat().st_size > 0
