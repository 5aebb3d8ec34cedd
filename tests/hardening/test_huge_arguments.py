"""Numbers an option's type takes but the command could not use (session 25, C): `robot serve --duration 1e308`,
`camera grab --timeout 1e308` and `slam noise --window 1e308` ended in OverflowError (exit 70), `fuse --start-pose
5=...` with two maps in IndexError (exit 70). Now: until Ctrl-C (a duration past any wait, as `fuse --live
--seconds` takes it), or one line and exit 2."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.datasets.conftest import run_cli, write_mrclam
from tests.hardening.test_map_metadata import _pair


def _with_default_sigint() -> None:
    """preexec_fn: the child gets SIGINT as a terminal's Ctrl-C would, whatever this test process inherited (a
    blocked SIGINT is inherited across exec: the Ctrl-C below then stayed pending and the test waited 60 s)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_serve_for_longer_than_a_wait_can_take_runs_until_ctrl_c() -> None:
    serve = subprocess.Popen([sys.executable, "-m", "runtime.cli", "robot", "serve", "--tcp", "0", "--duration",
                              "1e308"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             cwd=Path(__file__).resolve().parents[2], env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
                             preexec_fn=_with_default_sigint)
    try:
        assert "listening on" in serve.stdout.readline()
        assert "Ctrl-C to stop" in serve.stdout.readline()   # both lines are printed inside serve's Ctrl-C guard
        assert serve.poll() is None          # still serving (it ended at once, exit 70)
        serve.send_signal(signal.SIGINT)
        _, err = serve.communicate(timeout=60)
    finally:
        serve.kill()
    assert serve.returncode == 0 and err == "", err


@pytest.mark.parametrize("value", ["1e308", "86401"])
def test_grab_timeout_beyond_a_day_is_a_usage_error(value, tmp_path) -> None:
    status, _, err = run_cli("camera", "grab", "--mock", "--out", str(tmp_path), "--timeout", value)
    assert status == 2 and err.count("\n") == 1 and "--timeout" in err and "at most 86400" in err, err
    assert not list(tmp_path.iterdir())


def test_a_noise_window_longer_than_the_log_is_said(tmp_path) -> None:
    write_mrclam(tmp_path / "data", gz=False, seconds=60.0)
    for window in ("1e308", "61"):
        status, _, err = run_cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                                 str(tmp_path / "n.toml"), "--window", window)
        assert status == 2 and err.count("\n") == 1 and "longer than the odometry" in err, err
    assert not (tmp_path / "n.toml").exists()


@pytest.mark.parametrize("key", ["2", "5", "99999999999999999999"])
def test_a_start_pose_for_a_map_index_past_the_last_is_one_line(key, tmp_path) -> None:
    paths = []
    for k, m in enumerate(_pair()):
        m.save(tmp_path / f"m{k}.npz")
        paths.append(str(tmp_path / f"m{k}.npz"))
    status, _, err = run_cli("fuse", *paths, "--out", str(tmp_path / "f.npz"), "--start-pose", f"{key}=0,0,0",
                             "--start-pose", "0=0,0,0", "--start-sigma", "1,0.3")
    assert status == 2 and err.count("\n") == 1 and "neither an index (0 to 1)" in err, err


def _carmen(path: Path, scans: int) -> Path:
    import math

    import numpy as np

    angles = np.linspace(-math.pi / 2, math.pi / 2, 181)
    lines = []
    for i in range(scans):
        ranges = np.minimum(4.0 / np.maximum(np.abs(np.cos(angles)), 1e-3), 8.0) - 0.02 * i
        lines.append("FLASER 181 " + " ".join(f"{r:.3f}" for r in ranges) + f" {0.02 * i:.3f} 0 0 0 0 0 {i} host {i}")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(("scans", "step"), [(5, "5"), (5, "1000000000"), (1, "1")])
def test_a_scanmatch_step_the_log_cannot_give_is_a_usage_error(tmp_path, scans, step) -> None:
    """`scanmatch --step` as long as the log (or a log of one scan) was 'too few for step', exit 1: the user's
    arguments against the user's file, exit 2."""
    log = _carmen(tmp_path / "scans.log", scans)
    status, _, err = run_cli("scanmatch", str(log), "--step", step)
    assert status == 2 and err.count("\n") == 1 and "too few for one link" in err, (status, err)
    status, _, err = run_cli("scanmatch", str(_carmen(tmp_path / "more.log", 6)), "--step", "5")
    assert status == 0, err
