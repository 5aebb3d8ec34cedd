"""`p3at run/demo --exchange zenoh` with a robot whose name is no Zenoh key chunk (session 44, A): `run --name
'robot 1'` (a world, or a robot by URL, may carry such a name) started the mission and ended it at the first map
publication with "mission failed: robot name 'robot 1' must be 1-64 of A-Z a-z 0-9 _ -", exit 1, as a device's
failure. The name is now checked with the other inputs: one line, exit 2, before anything starts."""
from __future__ import annotations

import json

import pytest

from mocks.world import DEFAULT_WORLD_PATH
from runtime.cli import build_parser
from runtime.commands.demo import mission_inputs_problem
from tests.datasets.conftest import run_cli


@pytest.fixture
def world(tmp_path):
    """The packaged building with its robot1 renamed 'robot 1'."""
    doc = json.loads(DEFAULT_WORLD_PATH.read_text())
    path = tmp_path / "world.json"
    path.write_text(json.dumps(doc).replace('"robot1"', '"robot 1"'))
    return path


@pytest.mark.parametrize("argv", [["run", "--name", "robot 1"], ["demo"]], ids=" ".join)
def test_a_name_no_zenoh_key_takes_is_refused_before_the_start(world, tmp_path, argv):
    out = tmp_path / "out"
    status, _, err = run_cli(*argv, "--world", str(world), "--camera", "synthetic", "--exchange", "zenoh",
                             "--seconds", "2", "--rerun", "none", "--out", str(out), "--quiet")
    assert status == 2 and len(err.strip().splitlines()) == 1, err
    assert "'robot 1'" in err and "key chunk" in err and "mission failed" not in err
    assert not out.exists()


@pytest.mark.parametrize(("argv", "problem"), [
    (["run", "--name", "robot1", "--exchange", "zenoh"], None),                    # a name the key takes
    (["run", "--name", "robot 1", "--exchange", "inprocess"], None),               # no Zenoh: any world name
    (["run", "--robot", "socket://127.0.0.1:9", "--name", "robot.1", "--exchange", "zenoh"], "'robot.1'"),
    (["run", "--robot", "socket://127.0.0.1:9", "--exchange", "zenoh"], None),     # robot1 by default
])
def test_only_names_on_a_zenoh_exchange_are_held_to_the_key(world, tmp_path, argv, problem):
    args = build_parser(["run"]).parse_args([*argv, "--world", str(world), "--out", str(tmp_path / "o")])
    if "--name" in argv and argv[argv.index("--name") + 1] == "robot1":   # the renamed world has no robot1
        args.world = None
    found = mission_inputs_problem(args)
    assert (found is None) if problem is None else (problem in found), found
