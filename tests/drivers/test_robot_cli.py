"""``p3at robot info | drive | serve`` through runtime.cli.main, against the virtual P3-AT.

Speed independence: no test counts on how long something takes. Real-time waits are failure bounds
(FAILURE_BOUND); a drive that must end early is given far longer (DRIVE_SECONDS) than any loaded machine needs
to notice a closed server, so "it ended" is the observable, not "it ended within 1 s" (that goal is measured by
benchmarks/eval_malformed_files.py, which prints the figure).
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from mocks.p3at import serve_tcp
from mocks.world import World
from runtime.cli import main

FAILURE_BOUND = 60.0
DRIVE_SECONDS = 600.0  # ten times FAILURE_BOUND: a drive still running at FAILURE_BOUND did not notice the loss
# The commands' default --link-timeout (0.6 s) is for a robot on its own machine; here the served robot's thread
# shares this process (and a loaded CI machine) with the command, and was once silent for over 0.6 s (1 drive in
# 40 beside two busy loops said 'link lost'). Tests that are not about the link give it a timeout no starved
# thread reaches; the one that is gives DRIVE_SECONDS, so the loss it sees can only be the closed server.
LINK = ["--link-timeout", str(DRIVE_SECONDS)]
REPO = Path(__file__).resolve().parents[2]


def _with_default_sigint() -> None:
    """preexec_fn: the child gets SIGINT as a terminal's Ctrl-C would, whatever this test process inherited
    (an ignored or blocked SIGINT is inherited across exec, and then Ctrl-C could not stop the child)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _p3at(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", *args], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
                            preexec_fn=_with_default_sigint)


@pytest.fixture
def served() -> Iterator:
    """A virtual robot on the wall clock, the commands' subject (``p3at robot`` talks to a robot in real time), at
    1x: its thread needs 1.6 % of a core to keep up, 2.3 % at 2x, where it ran until session 47 (measured alone); its
    physics, which piles up when the thread is starved (a process given less falls behind without bound), halves."""
    world = World.load()
    server = serve_tcp(world, "robot1", port=0, seed=3)
    yield server
    server.close()


def test_info_json(served, capsys) -> None:
    assert main(["robot", "info", served.url, "--json", *LINK]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["identity"] == {"name": "robot1", "type": "Pioneer", "subtype": "p3at-sh"}
    assert info["config"]["watchdog"] == 2000 and info["params"].endswith("p3at-sh.json")
    assert info["state"]["x"] == 0.0 and len(info["state"]["sonars"]) == 16
    assert all(s["range_m"] is not None for s in info["state"]["sonars"])


def test_info_text(served, capsys) -> None:
    assert main(["robot", "info", served.url, *LINK]) == 0
    out = capsys.readouterr().out
    assert "robot1  (Pioneer p3at-sh)" in out and "sip_cycle=100" in out and "sonar m" in out


def test_drive_prints_odometry_and_moves_the_robot(served, capsys) -> None:
    start = served.world.pose("robot1").copy()
    assert main(["robot", "drive", served.url, "--vel", "0.4", "--rvel", "0", "--seconds", "2",
                 "--every", "0.25", "--json", *LINK]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(lines) >= 2  # at least one while driving (a starved process may print fewer than 8) and the last
    xs = [line["x"] for line in lines]
    # How far 2 s of wall clock take the robot depends on how much of them a loaded machine gives the server's
    # thread (0.8 s once gave under 0.2 m beside two busy loops); that it moved forward and says where does not.
    assert xs == sorted(xs) and xs[-1] > 0.02
    moved = float(np.linalg.norm(served.world.pose("robot1")[:2] - start[:2]))
    assert lines[-1]["v"] == 0.0 and moved == pytest.approx(xs[-1], abs=0.02)


def test_errors_are_one_line_and_nonzero(capsys, tmp_path) -> None:
    assert main(["robot", "info", str(tmp_path / "ttyNone")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("p3at robot info: ") and err.count("\n") == 1
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert main(["robot", "info", "socket://127.0.0.1:1", "--params", str(bad)]) == 2
    assert "bad.json:1" in capsys.readouterr().err
    assert main(["robot", "drive", "socket://127.0.0.1:1", "--seconds", "-1"]) == 2
    assert main(["robot", "serve", "--start-pose", "1,2"]) == 2
    assert "X,Y,TH" in capsys.readouterr().err
    assert main(["robot", "serve", "--name", "nobody"]) == 2


def test_drive_says_link_lost_and_exits_nonzero_when_the_server_closes(served) -> None:
    drive = _p3at("robot", "drive", served.url, "--vel", "0.2", "--seconds", str(DRIVE_SECONDS), "--every", "0.1",
                  *LINK)
    try:
        first = drive.stdout.readline()  # the column header: the robot is connected
        second = drive.stdout.readline()  # a state while driving
        assert "[rad]" in first and len(second.split()) == 6, (first, second)
        served.close()
        status = drive.wait(FAILURE_BOUND)
    finally:
        drive.kill()
    err = drive.stderr.read()
    assert status == 1
    assert err.startswith("p3at robot drive: ") and "link lost" in err and err.count("\n") == 1, err


def test_info_and_drive_print_radians_with_units(served, capsys) -> None:
    assert main(["robot", "info", served.url, *LINK]) == 0
    out = capsys.readouterr().out
    assert re.search(r"θ=[+-]\d\.\d{4} rad", out) and "deg" not in out
    assert main(["robot", "drive", served.url, "--seconds", "0.1", "--rvel", "0.3", *LINK]) == 0
    header = capsys.readouterr().out.splitlines()[0].split()
    assert header == ["t", "[s]", "x", "[m]", "y", "[m]", "θ", "[rad]", "v", "[m/s]", "ω", "[rad/s]"]


@pytest.mark.parametrize("arguments", [["--vel", "nan"], ["--rvel", "inf"], ["--seconds", "nan"],
                                       ["--every", "0"], ["--link-timeout", "-1"]])
def test_drive_refuses_nonsense_numbers(arguments, capsys) -> None:
    assert main(["robot", "drive", "socket://127.0.0.1:1", "--seconds", "1", *arguments]) == 2
    assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.parametrize("where", [["--tcp", "0"], ["--pty"]])
def test_serve_prints_where_it_listens_and_a_client_can_connect(where, capsys) -> None:
    # A separate process stopped with SIGINT (Ctrl-C) once the client is done: nothing races a --duration.
    server = _p3at("robot", "serve", *where, "--start-pose", "3,5,0", "--name", "cli")
    try:
        deadline = time.monotonic() + FAILURE_BOUND
        out = ""
        while "listening on" not in out and time.monotonic() < deadline and server.poll() is None:
            out += server.stdout.readline()
        url = re.search(r"listening on (\S+)", out).group(1)
        assert main(["robot", "info", url, "--json", *LINK]) == 0
        assert json.loads(capsys.readouterr().out)["identity"]["name"] == "cli"
        server.send_signal(signal.SIGINT)
        assert server.wait(FAILURE_BOUND) == 0
    finally:
        server.kill()
