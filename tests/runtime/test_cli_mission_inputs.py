"""``p3at demo`` and ``p3at run`` say what is wrong with their own files before any robot starts: one line naming the
command and the file, exit 2 (they said "p3at: mission failed: ..." with exit 1 once the mission was under way)."""
from __future__ import annotations

import pytest

from runtime.cli import main

MISSIONS = ("demo", "run")


def _one_line(capsys) -> str:
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and captured.out == "", (captured.out, err)
    return err[0]


def _mission(command: str, tmp_path, *more: str) -> list[str]:
    return [command, "--camera", "synthetic", "--seconds", "2", "--quiet", *more]


@pytest.mark.parametrize("command", MISSIONS)
def test_a_route_file_that_does_not_parse(command, tmp_path, capsys):
    route = tmp_path / "corridor.route"
    route.write_text("1 2\nfoo bar\n")
    code = main(_mission(command, tmp_path, "--route", str(route), "--out", str(tmp_path / "out")))
    line = _one_line(capsys)
    assert code == 2 and line.startswith(f"p3at {command}: {route}:2: bad waypoint"), line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", MISSIONS)
def test_a_missing_route_file(command, tmp_path, capsys):
    code = main(_mission(command, tmp_path, "--route", str(tmp_path / "nope.route"), "--out", str(tmp_path / "o")))
    assert code == 2 and _one_line(capsys) == f"p3at {command}: {tmp_path / 'nope.route'}: no such route file"


@pytest.mark.parametrize("command", MISSIONS)
@pytest.mark.parametrize("motion", ["explore", "none"])
def test_a_route_with_a_motion_that_follows_none(command, motion, tmp_path, capsys):
    # session 48: the run went ahead and ignored the route without a word
    route = tmp_path / "corridor.route"
    route.write_text("1 0\n2 0\n")
    code = main(_mission(command, tmp_path, "--route", str(route), "--motion", motion, "--out", str(tmp_path / "o")))
    assert code == 2 and _one_line(capsys) == (f"p3at {command}: --route {route}: only --motion route follows a "
                                               f"route (this run has --motion {motion})")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", MISSIONS)
def test_a_world_file_that_is_not_json(command, tmp_path, capsys):
    world = tmp_path / "building.json"
    world.write_bytes(b"\x89PNG\r\n\x1a\n not a building")
    code = main(_mission(command, tmp_path, "--world", str(world), "--out", str(tmp_path / "out")))
    line = _one_line(capsys)
    assert code == 2 and line.startswith(f"p3at {command}: {world}"), line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", MISSIONS)
def test_an_output_folder_that_is_a_file(command, tmp_path, capsys):
    taken = tmp_path / "robot1.npz"
    taken.write_bytes(b"a map")
    code = main(_mission(command, tmp_path, "--out", str(taken)))
    assert code == 2 and _one_line(capsys) == f"p3at {command}: --out {taken}: a file is there; give a folder"
    assert taken.read_bytes() == b"a map"


@pytest.mark.parametrize("command", MISSIONS)
def test_more_virtual_robots_than_the_building_has_starts(command, tmp_path, capsys):
    code = main(_mission(command, tmp_path, "--robots", "5", "--out", str(tmp_path / "out")))
    line = _one_line(capsys)
    assert code == 2 and line.startswith(f"p3at {command}: --robots 5: the world ") and "has 3 start poses" in line


@pytest.mark.parametrize("command", MISSIONS)
def test_logging_into_an_earlier_runs_log_is_refused_before_its_recording_is_replaced(command, tmp_path, capsys):
    """A second `p3at demo --log-sensors --out lg` failed (exit 1, 'mission failed: lg/robot1-log: already holds a
    sensor log') after it had replaced the first run's mission.rrd with an empty recording (0 robots)."""
    out = tmp_path / "lg"
    (out / "robot1-log").mkdir(parents=True)
    (out / "robot1-log" / "robot1-log_0.mcap").write_bytes(b"the first run's log")
    (out / "mission.rrd").write_bytes(b"the first run's recording")
    code = main(_mission(command, tmp_path, "--log-sensors", "--out", str(out)))
    line = _one_line(capsys)
    assert code == 2 and line == (f"p3at {command}: --out {out}: {out / 'robot1-log'} already holds a sensor log of "
                                  "an earlier run; give another --out (or move it)")
    assert (out / "mission.rrd").read_bytes() == b"the first run's recording"
    assert sorted(p.name for p in out.iterdir()) == ["mission.rrd", "robot1-log"]
