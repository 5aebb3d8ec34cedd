"""TUM trajectories: exact round trip, read by evo, validated on read; a mission writes them beside each map and
evo's ATE on them is the RMS position error."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from runtime.trajectories import TrajectoryFileError, TrajectoryRecorder, planar, read_tum, write_tum

_spec = importlib.util.spec_from_file_location(
    "evo_metrics", Path(__file__).resolve().parents[2] / "benchmarks" / "evo_metrics.py")
evo_metrics = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(evo_metrics)

_finite = st.floats(-1e4, 1e4, allow_nan=False)


@st.composite
def _rows(draw):
    n = draw(st.integers(1, 40))
    t = np.cumsum(draw(arrays(float, n, elements=st.floats(1e-3, 10.0)))) + draw(st.floats(0, 1e5))
    xy = draw(arrays(float, (n, 2), elements=_finite))
    theta = draw(arrays(float, n, elements=st.floats(-math.pi, math.pi)))
    return np.column_stack([t, xy, theta])


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=_rows())
def test_tum_round_trip_is_exact_and_evo_reads_the_same_poses(tmp_path, rows):
    path = tmp_path / "traj.tum"
    write_tum(path, rows, comment="test")
    back = planar(read_tum(path))
    np.testing.assert_array_equal(back[:, :3], rows[:, :3])  # t, x, y exactly
    np.testing.assert_allclose(np.cos(back[:, 3] - rows[:, 3]), 1.0, atol=1e-12)
    evo = evo_metrics.load(path)  # evo's own TUM reader
    np.testing.assert_array_equal(evo.timestamps, rows[:, 0])
    np.testing.assert_array_equal(evo.positions_xyz[:, :2], rows[:, 1:3])


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.lists(st.one_of(st.text(max_size=60), st.lists(st.sampled_from(
    ["1", "0", "-2.5", "nan", "inf", "1e308", "x", "0.5", "#"]), max_size=10).map(" ".join)), max_size=8))
def test_the_tum_reader_gives_a_clean_error_or_valid_rows(tmp_path, text):
    path = tmp_path / "fuzz.tum"
    path.write_bytes("\n".join(text).encode("utf-8", "surrogatepass"))
    try:
        rows = read_tum(path)
    except TrajectoryFileError as e:
        assert str(path) in str(e)
        return
    assert rows.shape[1] == 8 and np.all(np.isfinite(rows)) and np.all(np.diff(rows[:, 0]) > 0)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0, atol=1e-6)


def test_the_recorder_interpolates_the_truth_at_each_frames_time():
    start = np.array([2.0, 1.0, math.pi / 2])
    truth = {"pose": start}
    recorder = TrajectoryRecorder(start)
    for k in range(11):  # the robot drives along world +y (its own +x) at 1 m/s, SIPs at 10 Hz
        truth["pose"] = start + [0.0, 0.1 * k, 0.0]
        recorder.add_truth(0.1 * k, lambda: truth["pose"])
    recorder.add_frame(0.25, np.array([0.25, 0.0, 0.0]), np.array([0.3, 0.0, 0.0]))
    recorder.add_frame(2.0, np.array([2.0, 0.0, 0.0]), None)  # after the last SIP: no truth row
    np.testing.assert_allclose(recorder.get("truth"), [[0.25, 0.25, 0.0, 0.0]], atol=1e-12)
    assert len(recorder.get("estimated")) == 2 and len(recorder.get("odometry")) == 1


@pytest.mark.slow
def test_a_mission_writes_tum_files_that_evo_scores(tmp_path):
    from runtime.mission import Mission, MissionConfig

    config = MissionConfig(robots=1, seconds=12.0, seed=2, camera="synthetic", camera_rate=5.0, particles=20,
                           fusion_interval=0.0, out=tmp_path, rerun="none")
    result = Mission(config).run()
    files = {p.name for p in tmp_path.glob("robot1*.tum")}
    assert files == {"robot1.tum", "robot1-odometry.tum", "robot1-truth.tum"}
    assert sorted(result.summary["robots"]["robot1"]["trajectory_files"]) == sorted(
        str(tmp_path / f) for f in files)
    estimated, truth = planar(read_tum(tmp_path / "robot1.tum")), planar(read_tum(tmp_path / "robot1-truth.tum"))
    assert len(estimated) == result.summary["robots"]["robot1"]["frames_processed"]
    assert np.ptp(truth[:, 1]) + np.ptp(truth[:, 2]) > 0.5  # the robot moved
    scores = evo_metrics.evaluate(tmp_path / "robot1-truth.tum", tmp_path / "robot1.tum", delta=0.5)
    common = np.isin(estimated[:, 0], truth[:, 0])
    by_hand = np.sqrt(np.mean(np.sum((estimated[common, 1:3] - truth[:, 1:3]) ** 2, axis=1)))
    assert scores["poses"] == len(truth) and scores["ate_rmse_m"] == pytest.approx(by_hand, rel=1e-9)
    assert scores["ate_rmse_m"] < 0.3  # exact wheel odometry, a synthetic camera: centimetres, not metres
    assert evo_metrics.main([str(tmp_path / "robot1-truth.tum"), str(tmp_path / "robot1-odometry.tum")]) == 0
