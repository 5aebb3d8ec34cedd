"""A `--rerun` URL Rerun refuses (session 23): one line naming it, exit 2. Before, `fuse --live` and `slam dataset`
(after its run) ended in exit 70, `internal error: RuntimeError: invalid endpoint ...`."""
from __future__ import annotations

import json

import pytest

from runtime.fleet.processes import free_port
from tests.datasets.conftest import run_cli

BAD = "rerun+http://256.0.0.1:99999/proxy"


def test_open_recording_says_a_bad_url_as_a_viewer_error() -> None:
    from runtime.rerun_sink import ViewerError, open_recording

    with pytest.raises(ViewerError, match=r"^--rerun rerun\+http://256\.0\.0\.1:99999/proxy: .*invalid") as info:
        open_recording(BAD)
    assert "\n" not in str(info.value)


def test_fuse_live_with_a_bad_rerun_url_is_exit_2(tmp_path) -> None:
    config = tmp_path / "node.json5"
    config.write_text(json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{free_port()}"]}}))
    status, _, err = run_cli("fuse", "--live", "--exchange", f"zenoh:{config}", "--seconds", "1", "--rerun", BAD)
    assert status == 2 and f"--rerun {BAD}" in err and "internal error" not in err, err


@pytest.mark.parametrize("argv", [["demo"], ["demo", "--processes"], ["run"]], ids=" ".join)
def test_demo_and_run_say_a_bad_rerun_url_as_a_usage_error_before_they_start(argv, tmp_path) -> None:
    """Session 23 left it: the URL was found only when the mission opened its recording, `p3at: mission failed:
    --rerun URL: ...`, exit 1 (a usage error is exit 2); `demo --processes` opened it in the fusion node."""
    out = tmp_path / "out"
    status, _, err = run_cli(*argv, "--rerun", BAD, "--seconds", "1", "--quiet", "--out", str(out))
    assert status == 2 and err.count("\n") == 1 and err.startswith(f"p3at {argv[0]}: --rerun {BAD}: "), err
    assert "invalid IPv4 address" in err and "mission failed" not in err
    assert not out.exists()   # said before anything ran or was written


@pytest.mark.parametrize("url", ["rerun+http://foo", "http://127.0.0.1:9876/proxy", "rerun+http://127.0.0.1:9876"])
def test_every_url_rerun_refuses_is_said_with_its_reason(url, tmp_path) -> None:
    status, _, err = run_cli("run", "--rerun", url, "--seconds", "1", "--quiet", "--out", str(tmp_path / "o"))
    assert status == 2 and err.count("\n") == 1 and f"--rerun {url}: invalid endpoint" in err, err


def test_a_url_rerun_takes_is_not_refused() -> None:
    from runtime.commands.options import rerun_url_problem

    assert rerun_url_problem("rerun+http://127.0.0.1:9876/proxy") is None   # no viewer needed: nothing connects
    for sink in ("file", "none", "spawn", "out/x.rrd", None):
        assert rerun_url_problem(sink) is None


def test_slam_dataset_says_a_bad_rerun_url_before_its_run(tmp_path) -> None:
    """`slam dataset` ran the whole log and wrote its map before Rerun refused the URL (session 24: said first)."""
    from tests.datasets.conftest import write_mrclam

    folder, out = tmp_path / "data", tmp_path / "map.npz"
    write_mrclam(folder, gz=False)
    status, _, err = run_cli("slam", "dataset", "mrclam", str(folder), "--robot", "1", "--out", str(out),
                             "--rerun", BAD)
    assert status == 2 and err.count("\n") == 1 and f"--rerun {BAD}: invalid endpoint" in err, err
    assert not out.exists()
