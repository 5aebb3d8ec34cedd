"""The data set run's frame reliability (``frame_reliability_*`` of a smoothed run, estimation.frame_reliability): a
log whose frame rests on one lone first sighting is flagged, with or without its truth, and ``p3at slam dataset``
says so on stderr beside its JSON; a log whose first frame sees several landmarks is not; MRCLAM robot 1's frame
rests on its first sighting (7.00 s, landmark 11), which its recording draws, and robot 2's does not."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import RangeBearingLog
from estimation.fastslam import range_bearing_config
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from tests.runtime.rerun_helpers import entity_rows

from .conftest import run_cli
from .turning_start import NOISE
from .turning_start import turning_start_log as _log


def _run(log: RangeBearingLog) -> dict:
    return run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(0), noise=NOISE,
                            association="id", robot="robot1", smooth=True).metrics


def test_a_log_whose_frame_rests_on_its_first_sighting_is_flagged_with_or_without_its_truth():
    m = _run(_log(1))
    assert m["frame_reliability_unchecked"]
    first = m["frame_reliability_heading_sighting"]
    assert first["time_s"] == pytest.approx(1.0) and first["component"] == "bearing"
    assert first["component_redundancy"] < 0.05                         # 0.011
    assert m["frame_reliability_effect_sd"][2] > 2 * m["frame_reliability_delta0"]      # 35 σ
    # the figures come from the design: the same without any truth (no score, the same flag)
    blind = _run(_log(1, with_truth=False))
    assert "unscored" in blind and "landmark_frame_sd" not in blind
    for key in ("frame_reliability_sd", "frame_reliability_effect", "frame_reliability_effect_sd"):
        np.testing.assert_allclose(blind[key], m[key], rtol=1e-6)
    assert blind["frame_reliability_unchecked"]
    # several first sightings tie the frame: no coordinate moves by δ₀ σ (3.0 σ at most)
    several = _run(_log(3))
    assert not several["frame_reliability_unchecked"]
    assert max(several["frame_reliability_effect_sd"]) < several["frame_reliability_delta0"]
    assert 0 < several["sighting_redundancy_min"] <= several["sighting_redundancy_median"] < 2


def _command_on_the_circle(tmp_path, synthetic) -> tuple[int, str, str]:
    """``p3at slam dataset ... --json`` on the synthetic circle (40 s), a model of σ 0.01 everywhere."""
    synthetic.write(tmp_path / "data", seconds=40.0)
    noise = tmp_path / "noise.toml"
    NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2),
               RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV,
                                 max_range_m=synthetic.SENSOR_RANGE)).save(noise)
    return run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--noise", str(noise),
                   "--particles", "10", "--out", str(tmp_path / "map.npz"), "--json")


def test_the_command_prints_the_figures_and_no_warning_when_the_frame_is_checked(tmp_path, synthetic):
    status, out, err = _command_on_the_circle(tmp_path, synthetic)
    assert status == 0, err
    m = json.loads(out)
    assert len(m["frame_reliability_sd"]) == 3 and m["frame_reliability_unchecked"] is False
    assert "frame rests" not in err and not any("frame rests" in w for w in m["warnings"])


def test_a_diagnosis_that_fails_loses_no_map_and_says_so(tmp_path, synthetic, monkeypatch):
    """The figures fail numerically (an information matrix that is not positive definite): the command still writes
    the map, exits 0, and says in one warning, on stderr beside its JSON, that the figures are missing and why."""
    import estimation.dataset_smoothing as smoothing

    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("Matrix is not positive definite")

    monkeypatch.setattr(smoothing, "reliability_metrics", broken)
    status, out, err = _command_on_the_circle(tmp_path, synthetic)
    assert status == 0, err
    m = json.loads(out)
    assert (tmp_path / "map.npz").is_file() and m["landmarks"] > 0
    assert m["reliability_unavailable"] == "LinAlgError: Matrix is not positive definite"
    assert "frame_reliability_sd" not in m
    [line] = [w for w in err.splitlines() if "could not be computed" in w]
    assert "(LinAlgError: Matrix is not positive definite)" in line and "written without them" in line


@pytest.mark.slow   # two whole MRCLAM logs, each a filter and the smoother (~15 s CPU each)
@pytest.mark.timeout(1200)
def test_real_dataset2_robot1_s_frame_rests_on_its_first_sighting_and_robot2_s_does_not(mrclam_dir, tmp_path):
    """`p3at slam dataset mrclam DIR --robot 1 --json` (the log's own fitted model): the warning on stderr names the
    sighting at 7.00 s of landmark 11, the only tie of the map's frame beyond the first turn's odometry (its bearing
    0.067 rad off the truth turned the frame 0.055 rad with the leave-one-out model, session 41 (A)). Robot 2's first
    seconds see landmarks that check each other."""
    status, out, err = run_cli("slam", "dataset", "mrclam", str(mrclam_dir), "--robot", "1", "--out",
                               str(tmp_path / "robot1.npz"), "--rerun", str(tmp_path / "robot1.rrd"), "--json")
    assert status == 0, err
    m = json.loads(out)
    assert m["frame_reliability_unchecked"]
    assert "warning: the map's frame rests on single sightings" in err and "7.00 s (landmark 11" in err
    for which in ("heading", "translation"):
        sighting = m[f"frame_reliability_{which}_sighting"]
        assert sighting["time_s"] == pytest.approx(7.0) and sighting["landmark"] == 11
    # the recording holds the same warnings, and draws that sighting from the first pose to landmark 11
    events = entity_rows(tmp_path / "robot1.rrd", "mission/events")
    assert [text for row in events for text in row["TextLog:text"]] == m["warnings"]
    [tie] = entity_rows(tmp_path / "robot1.rrd", "map/robot1/frame_tie")
    assert "(landmark 11," in tie["Points2D:labels"][0]
    np.testing.assert_allclose(tie["Points2D:positions"][0], [0.0, 0.0], atol=1e-6)    # 7.00 s is pose 0
    assert entity_rows(tmp_path / "robot1.rrd", "map/robot1/frame_tie/ray")
    status, out, err = run_cli("review", str(tmp_path / "robot1.rrd"), "--no-export")
    assert status == 0, err
    assert [line for line in out.splitlines() if "WARNING" in line] == [f"  WARNING: {w}" for w in m["warnings"]]
    status, out, err = run_cli("slam", "dataset", "mrclam", str(mrclam_dir), "--robot", "2", "--out",
                               str(tmp_path / "robot2.npz"), "--json")
    assert status == 0, err
    m = json.loads(out)
    assert not m["frame_reliability_unchecked"] and "frame rests" not in err
