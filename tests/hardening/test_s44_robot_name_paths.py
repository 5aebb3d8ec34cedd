"""A robot's name names its files (OUT/NAME.npz, .ply, .tum, NAME-log/), and a world file or `run --name` gives it
(session 44, A). `p3at demo --world W` with W's robot1 renamed '../escape' wrote escape.npz, .ply and three .tum
files beside --out, outside it; `run --robot URL --name ../x` would write OUT/../x.npz. A world's robot name with a
slash, '..', surrounding spaces or a character that does not print is now a WorldFileError naming the field, and
such a --name one line, exit 2, before anything starts; names like 'robot 1' or 'Roboter-Ä' still serve."""
from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.world import DEFAULT_WORLD_PATH, World, WorldFileError
from tests.datasets.conftest import run_cli


def _world(tmp_path, name: str):
    doc = json.loads(DEFAULT_WORLD_PATH.read_text())
    doc["start_poses"][name] = doc["start_poses"].pop("robot1")
    doc["routes"][name] = doc["routes"].pop("robot1")
    path = tmp_path / "world.json"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("name", ["../escape", "a/b", "..", ".", "x\\y", "robot\n1", " robot1", "r" * 65, ""])
def test_a_world_robot_name_that_would_leave_the_folder_is_refused(tmp_path, name):
    path = _world(tmp_path, name)
    with pytest.raises(WorldFileError) as error:
        World.load(path)
    assert str(path) in str(error.value) and "robot's name" in str(error.value) and "\n" not in str(error.value)


@settings(max_examples=60, deadline=None)
@given(name=st.text(min_size=1, max_size=70))
def test_any_world_robot_name_loads_or_is_refused_by_the_one_rule(tmp_path_factory, name):
    from mocks.world import robot_name_problem

    path = _world(tmp_path_factory.mktemp("w"), name)
    if robot_name_problem(name) is None:
        assert name in World.load(path).start_poses
        assert "/" not in name and name not in (".", "..") and name.isprintable()
    else:
        with pytest.raises(WorldFileError, match="robot's name"):
            World.load(path)


def test_demo_writes_nothing_outside_its_folder(tmp_path):
    world = _world(tmp_path, "../escape")
    out = tmp_path / "runs" / "out"
    status, _, err = run_cli("demo", "--world", str(world), "--camera", "synthetic", "--seconds", "2",
                             "--rerun", "none", "--out", str(out), "--quiet")
    assert status == 2 and len(err.strip().splitlines()) == 1 and "start_poses" in err, err
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("name", ["../x", "a/b", "..", "x\x1by"])
def test_run_refuses_such_a_name_before_the_start(tmp_path, name):
    status, _, err = run_cli("run", "--robot", "socket://127.0.0.1:9", "--name", name, "--out", str(tmp_path / "o"))
    assert status == 2 and len(err.strip().splitlines()) == 1 and "--name" in err and "robot's name" in err, err
    assert not (tmp_path / "o").exists()


def test_names_of_every_printable_kind_still_serve(tmp_path):
    for name in ("robot 1", "Roboter-Ä", "r.1", "机器人"):
        assert name in World.load(_world(tmp_path, name)).start_poses
