"""The drive's shaped response in the MRCLAM benchmarks: eval_mrclam's ``--drive-shape``, mrclam_drive_response's
shape fit (``--section shape``) and mrclam_response_maps' comparison of segments (session 45 (B))."""
from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from benchmarks import eval_mrclam, mrclam_drive_response, mrclam_response_maps
from estimation.datasets import RangeBearingLog, integrate_velocities
from estimation.odometry_response import ResponseShape, with_drive_shape
from tests.datasets.conftest import MRCLAM2


def test_drive_shape_option_reads_one_or_two_shapes():
    turn, travel = eval_mrclam.drive_shape_option("0.15,0,0.3,0.45/0,0.5,0,0")
    assert turn == ResponseShape(0.15, 0.0, 0.3, 0.45) and travel == ResponseShape(0.0, 0.5)
    assert eval_mrclam.drive_shape_option("0.1,0.05,0,0") == (ResponseShape(0.1, 0.05),) * 2


@pytest.mark.parametrize("text", ["0.1,0.05", "0.1,0.05,0,0/0.1", "-0.1,0,0,0", "0.1,0,0,0.3", "a,b,c,d",
                                  "0.1,0,0,0/0,0,0,0/0,0,0,0", "0.1,nan,0,0", "3,0,0,0"])
def test_drive_shape_option_refuses_what_is_no_shape(text):
    with pytest.raises(argparse.ArgumentTypeError, match="DEAD,FAST,SLOW,WEIGHT"):
        eval_mrclam.drive_shape_option(text)


def test_eval_mrclam_takes_one_description_of_the_drive(capsys):
    with pytest.raises(SystemExit) as exit_:
        eval_mrclam.main(["--drive-shape", "0.15,0,0.3,0.45", "--response-time", "0.2"])
    assert exit_.value.code == 2
    assert "give one" in capsys.readouterr().err


@pytest.mark.timeout(600)
def test_eval_mrclam_runs_through_a_drive_shape_and_says_so(tmp_path, capsys):
    if not (MRCLAM2 / "Robot1_Odometry.dat.gz").is_file() and not (MRCLAM2 / "Robot1_Odometry.dat").is_file():
        pytest.skip(f"MRCLAM data set 2 not found in {MRCLAM2.resolve()} (../shared/data/mrclam, see its README)")
    assert eval_mrclam.main(["--data", str(MRCLAM2), "--robots", "2", "--association", "id", "--until", "120",
                             "--maps", str(tmp_path / "maps"), "--odometry-lag", "--particles", "20",
                             "--drive-shape", "0.15,0,0.3,0.45/0,0.5,0,0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["drive_shape"] == [[0.15, 0.0, 0.3, 0.45], [0.0, 0.5, 0.0, 0.0]]
    assert out["runs"]["id/robot2"]["ate_m"] < 0.5


def test_response_maps_reads_its_drive_and_refuses_others():
    label, drive = mrclam_response_maps.drive_option("shape:0.15,0,0.3,0.45/0,0.5,0,0")
    assert label.startswith("shape:") and callable(drive)
    for text in ("response:-1", "response:x", "lag:0.2", "shape:1,2"):
        with pytest.raises(argparse.ArgumentTypeError):
            mrclam_response_maps.drive_option(text)


def test_segments_are_compared_pair_by_pair():
    """Wins and medians of the paired differences, per robot and pooled."""
    rows = {1: {"as read": [{"ate_m": a, "aligned_ate_m": 0.03} for a in (0.10, 0.20, 0.30)],
                "drive": [{"ate_m": a, "aligned_ate_m": 0.03} for a in (0.05, 0.25, 0.30)]},
            2: {"as read": [{"ate_m": 0.1, "aligned_ate_m": 0.02}] * 7,
                "drive": [{"ate_m": 0.2, "aligned_ate_m": 0.02}] * 7}}
    table = {row["robot"]: row for row in mrclam_response_maps.compare_segments(rows)}
    assert (table["1"]["ate_m"]["drive_better"], table["1"]["ate_m"]["drive_worse"]) == (1, 1)
    assert table["1"]["ate_m"]["median_difference"] == pytest.approx(0.0)
    assert table["all"]["segments"] == 10 and table["all"]["ate_m"]["drive_worse"] == 8
    assert table["2"]["ate_m"]["median_drive"] == pytest.approx(0.2)
    assert table["all"]["ate_m"]["p"] < 0.05


def _simulated(seconds: float, turn: ResponseShape, travel: ResponseShape, seed: int) -> RangeBearingLog:
    """A robot whose command changes at random every 0.3-1.5 s (resting a third of the time), its truth the command
    through ``turn`` and ``travel`` (Vicon-like rows every 10 ms)."""
    rng = np.random.default_rng(seed)
    t = np.round(np.arange(0.0, seconds, 0.02), 2)
    v, w = np.zeros_like(t), np.zeros_like(t)
    k = 0
    while k < len(t):
        n = int(rng.uniform(15, 75))
        still = rng.random() < 0.33
        v[k:k + n], w[k:k + n] = (0.0, 0.0) if still else (rng.uniform(0, 0.3), rng.uniform(-0.5, 0.5))
        k += n
    command = RangeBearingLog("sim", integrate_velocities(t, v, w), np.zeros(0), np.zeros(0), np.zeros(0),
                              np.zeros(0, np.int64), velocities=np.column_stack([t, v, w]))
    fine = np.arange(0.0, seconds - 1.0, 0.01)
    rows = np.column_stack([fine, with_drive_shape(command, turn, travel).odometry_pose(fine)])
    return RangeBearingLog("sim", command.odometry, np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64),
                           ground_truth=rows, velocities=command.velocities)


@pytest.mark.timeout(1200)  # 183 s in a loaded CI run (session 47): the CPU-bound tests get 1200
def test_the_shape_fit_finds_a_dead_time_a_jump_and_a_tail_on_held_out_halves():
    """Logs whose truth is the command through a dead time of 0.15 s, 55 % at once and 45 % with 0.3 s (the turn),
    and 0.5 s (the travel): on each half, the fast + slow family finds that turn shape within a grid step and beats the
    pure delay and the single first order on the other half; the travel's first order finds 0.5 s."""
    turn, travel = ResponseShape(0.15, 0.0, 0.3, 0.45), ResponseShape(0.0, 0.5)
    logs = {r: _simulated(1900.0, turn, travel, r) for r in (1, 2)}
    result = mrclam_drive_response.shape_fits(logs, 0.25)
    for half in (0, 1):
        fitted = result["turn"][f"{half}/fast + slow"]
        s = fitted["shape"]
        assert s["dead_time_s"] == pytest.approx(0.15, abs=0.006)
        assert (s["fast_s"], s["slow_s"]) == (0.0, 0.3) and s["slow_weight"] == pytest.approx(0.45, abs=0.051)
        for other in ("delay", "first order"):
            assert fitted["held_out_pooled"][0.25] < result["turn"][f"{half}/{other}"]["held_out_pooled"][0.25]
        v = result["travel"][f"{half}/first order"]["shape"]
        assert v["fast_s"] == pytest.approx(0.5) and v["dead_time_s"] <= 0.011
