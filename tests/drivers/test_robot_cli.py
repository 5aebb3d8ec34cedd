"""``p3at robot info | drive | serve`` through runtime.cli.main, against the virtual P3-AT."""
from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from mocks.p3at import serve_tcp
from mocks.world import World
from runtime.cli import main


@pytest.fixture
def served() -> Iterator:
    world = World.load()
    server = serve_tcp(world, "robot1", port=0, time_scale=2.0, seed=3)
    yield server
    server.close()


def test_info_json(served, capsys) -> None:
    assert main(["robot", "info", served.url, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["identity"] == {"name": "robot1", "type": "Pioneer", "subtype": "p3at-sh"}
    assert info["config"]["watchdog"] == 2000 and info["params"].endswith("p3at-sh.json")
    assert info["state"]["x"] == 0.0 and len(info["state"]["sonars"]) == 16
    assert all(s["range_m"] is not None for s in info["state"]["sonars"])


def test_info_text(served, capsys) -> None:
    assert main(["robot", "info", served.url]) == 0
    out = capsys.readouterr().out
    assert "robot1  (Pioneer p3at-sh)" in out and "sip_cycle=100" in out and "sonar m" in out


def test_drive_prints_odometry_and_moves_the_robot(served, capsys) -> None:
    start = served.world.pose("robot1").copy()
    assert main(["robot", "drive", served.url, "--vel", "0.4", "--rvel", "0", "--seconds", "0.8",
                 "--every", "0.2", "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(lines) >= 4
    xs = [line["x"] for line in lines]
    assert xs == sorted(xs) and xs[-1] > 0.2
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
    assert main(["robot", "serve", "--pose", "1,2"]) == 2
    assert "X,Y,TH" in capsys.readouterr().err
    assert main(["robot", "serve", "--name", "nobody"]) == 2


@pytest.mark.parametrize("where", [["--tcp", "0"], ["--pty"]])
def test_serve_prints_where_it_listens_and_a_client_can_connect(where, capsys) -> None:
    status: list[int] = []
    thread = threading.Thread(target=lambda: status.append(
        main(["robot", "serve", *where, "--pose", "3,5,0", "--name", "cli", "--duration", "1.5"])))
    thread.start()
    try:
        out = ""
        deadline = time.monotonic() + 5
        while "listening on" not in out and time.monotonic() < deadline:
            time.sleep(0.05)
            out += capsys.readouterr().out
        url = re.search(r"listening on (\S+)", out).group(1)
        assert main(["robot", "info", url, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["identity"]["name"] == "cli"
    finally:
        thread.join(10)
    assert status == [0]
