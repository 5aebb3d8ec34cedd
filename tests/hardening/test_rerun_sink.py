"""A `--rerun` sink that is no keyword, no URL and no FILE.rrd (session 24's leftover, fixed in session 25, C): one
line, exit 2, before anything runs. Before, `demo`/`run`/`fuse --live --rerun foo` (a mistyped `file`?) saved the
recording to a file named 'foo' (exit 0), and `--rerun DIR` ended in Rerun's warnings and exit 1. `fuse --live` with
map files ignored them without a word. The URL prefixes are spelled once (runtime/commands/options.py)."""
from __future__ import annotations

import pytest

from runtime.commands.options import rerun_sink_problem
from runtime.limits import RERUN_URL_PREFIXES
from tests.datasets.conftest import run_cli

MISSION = ["--camera", "synthetic", "--seconds", "1", "--quiet"]


@pytest.mark.parametrize("command", ["demo", "run"])
@pytest.mark.parametrize("sink", ["foo", "fille", "out.txt"])
def test_demo_and_run_refuse_a_sink_that_is_no_keyword_url_or_rrd(command, sink, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    status, _, err = run_cli(command, *MISSION, "--out", "o", "--rerun", sink)
    assert status == 2 and err.count("\n") == 1, err
    assert err.startswith(f"p3at {command}: --rerun {sink}: give file, spawn, none, FILE.rrd or a rerun+http:// URL")
    assert sorted(p.name for p in tmp_path.iterdir()) == []   # nothing ran, no file 'foo'


def test_a_rrd_sink_that_is_a_folder_is_refused_before_the_mission(tmp_path) -> None:
    folder = tmp_path / "x.rrd"
    folder.mkdir()
    status, _, err = run_cli("run", *MISSION, "--out", str(tmp_path / "o"), "--rerun", str(folder))
    assert status == 2 and err.count("\n") == 1 and "is a folder" in err, err
    assert not (tmp_path / "o").exists()


def test_a_rrd_sink_is_written_where_it_is_named(tmp_path) -> None:
    target = tmp_path / "rec" / "mine.rrd"
    status, _, err = run_cli("run", *MISSION, "--out", str(tmp_path / "o"), "--rerun", str(target))
    assert status == 0, err
    status, out, err = run_cli("review", str(target), "--no-export")
    assert status == 0 and "robot1" in out, err


def test_fuse_live_refuses_a_bad_sink_and_map_files(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    live = ["fuse", "--live", "--exchange", "inprocess", "--seconds", "1"]
    status, _, err = run_cli(*live, "--rerun", "foo")
    assert status == 2 and err.count("\n") == 1 and "--rerun foo: give file, spawn, none" in err, err
    status, _, err = run_cli(*live, "a.npz", "b.npz")
    assert status == 2 and err.count("\n") == 1 and "do not apply to --live" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("prefix", RERUN_URL_PREFIXES)
def test_every_url_prefix_is_a_url_to_the_check_and_to_the_recording(prefix) -> None:
    """The check and open_recording read one list: a URL the check sends to Rerun's parser, open_recording connects
    to (the bad address below is refused by both the same way, never saved to a file of that name)."""
    from runtime.rerun_sink import ViewerError, open_recording

    sink = f"{prefix}256.0.0.1:99999/proxy"
    problem = rerun_sink_problem(sink, ("file",))
    assert problem is not None and problem.startswith(f"--rerun {sink}: ") and "FILE.rrd" not in problem
    with pytest.raises(ViewerError, match=r"^--rerun "):
        open_recording(sink)
