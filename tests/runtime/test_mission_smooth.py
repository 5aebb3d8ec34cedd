"""--smooth: at the mission's end each robot's map is smoothed over the readings it kept, and the final fusion uses it.

Short missions (10 simulated seconds, the synthetic camera), as tests/runtime/test_mission.py's shortest two-robot one.
"""
from __future__ import annotations

import numpy as np
import pytest

import estimation.stereo_readings as stereo_readings
from estimation.landmark_map import LandmarkMap
from runtime.mission import Mission, MissionConfig
from runtime.report import format_summary

ROBOTS = ("robot1", "robot2")


def _config(out, **changes) -> MissionConfig:
    settings = dict(robots=2, seconds=10.0, seed=5, camera="synthetic", camera_rate=10.0, particles=30,
                    fusion_interval=5.0, out=out, rerun="none", odometry="realistic")
    return MissionConfig(**(settings | changes))


def _ate(folder, m: LandmarkMap) -> float:
    """RMS position error (m) of the map's trajectory against the robot's true one (its TUM file) on the same frames."""
    rows = np.loadtxt(folder / f"{m.robot}-truth.tum")   # t x y z qx qy qz qw, in the map's frame
    traj = m.trajectory[1:]
    k = np.clip(np.searchsorted(rows[:, 0], traj[:, 0]), 0, len(rows) - 1)
    ok = np.abs(rows[k, 0] - traj[:, 0]) < 1e-6
    assert ok.sum() > 0.9 * len(traj)
    return float(np.sqrt(np.mean(np.sum((traj[ok, 1:3] - rows[k[ok], 1:3]) ** 2, axis=1))))


@pytest.fixture(scope="module")
def smoothed(tmp_path_factory):
    out = tmp_path_factory.mktemp("smooth")
    events: list[str] = []
    result = Mission(_config(out, smooth=True), events=events.append).run()
    return out, result, events


@pytest.mark.slow
def test_smooth_fuses_smoothed_maps_that_differ_from_the_filters_and_are_no_worse_against_the_truth(smoothed):
    out, result, events = smoothed
    assert not result.failures
    assert result.summary["smoothed"] is True
    fused = LandmarkMap.load(out / "fused.npz")
    for name in ROBOTS:
        figures = result.summary["robots"][name]["smoothing"]
        assert figures["smoothed"] and figures["reason"] is None
        assert result.summary["robots"][name]["frames_too_near"] == 0   # the synthetic camera: observations, no images
        assert 0 < figures["inliers"] <= figures["associated"] <= figures["readings"] == figures["readings_kept"]
        assert figures["cut"] == figures["associated"] - figures["inliers"]
        assert np.isfinite(figures["chi2_per_dof"]) and figures["chi2_per_dof"] > 0
        assert result.summary["robots"][name]["filter_map_file"] == str(out / f"{name}-filter.npz")
        smooth, filt = LandmarkMap.load(out / f"{name}.npz"), LandmarkMap.load(out / f"{name}-filter.npz")
        assert np.array_equal(smooth.ids, filt.ids)
        assert np.abs(smooth.positions - filt.positions).max() > 1e-4
        assert np.abs(smooth.trajectory[1:, 1:] - filt.trajectory[1:, 1:]).max() > 1e-4
        assert smooth.metadata["smoothed"]["inliers"] == figures["inliers"]
        # the smoothed map carries its own self-check (the filter's re-run along the smoothed poses), the filter's too
        assert smooth.metadata["filter_self_check"] == filt.metadata["self_check"]
        # keyframes: fewer frames smoothed than seen, the smoothed trajectory at every frame, the re-run on keyframes
        assert 2 <= figures["frames"] < figures["frames_seen"] == len(smooth.trajectory) - 1
        assert smooth.metadata["self_check"]["frames"] == figures["frames"]
        assert smooth.metadata["self_check"]["lost"] is False
        assert _ate(out, smooth) <= _ate(out, filt)
        np.testing.assert_array_equal(result.maps[name].positions, smooth.positions)
        assert any(e.startswith(f"{name}: the final map is smoothed:") for e in events), events
        assert f"{name}: map smoothed after the mission" in format_summary(result.summary)
        # the odometry's scales estimated with the poses: the mock's (OdometryErrors.realistic: wheels 0.99, track
        # 1.03, so turns read 0.99 / 1.03) within 4σ, σ no wider than the prior's 0.05, said in the summary
        scales, sd = np.array(figures["odometry_scales"]), np.array(figures["odometry_scale_sd"])
        assert np.all(sd > 0) and np.all(sd <= 0.05)
        assert np.all(np.abs(scales - [0.99, 0.99 / 1.03]) <= 4 * sd), (scales, sd)
        assert smooth.metadata["smoothed"]["odometry_scales"] == figures["odometry_scales"]
        assert f"odometry scales: distance {scales[0]:.3f} ± {sd[0]:.3f}" in format_summary(result.summary)
    # the final fusion was made of the smoothed maps: robot 1's landmarks (the reference frame) are in the fused map
    # as smoothed, not as the filter left them
    ref_smooth, ref_filter = (LandmarkMap.load(out / f"robot1{s}.npz").positions for s in ("", "-filter"))
    moved = np.linalg.norm(ref_smooth - ref_filter, axis=1) > 1e-4
    in_fused = [np.linalg.norm(fused.positions[None] - p[:, None], axis=2).min(axis=1) < 1e-9
                for p in (ref_smooth, ref_filter)]
    assert np.mean(in_fused[0][moved]) > 0.5 and not np.any(in_fused[1][moved])


@pytest.mark.slow
def test_smooth_past_the_cap_says_why_and_keeps_the_filters_map(tmp_path, monkeypatch):
    monkeypatch.setattr(stereo_readings, "MAX_FRAMES", 3)
    events: list[str] = []
    result = Mission(_config(tmp_path, robots=1, seconds=2.0, smooth=True), events=events.append).run()
    assert not result.failures
    figures = result.summary["robots"]["robot1"]["smoothing"]
    assert not figures["smoothed"] and "cap of 3 frames" in figures["reason"]
    assert result.summary["smoothed"] is False
    said = [e for e in events if "cap of 3 frames" in e]
    assert said[0].startswith("robot1: smoothing: past the smoothing's cap") and len(said) == 2, events  # now, at end
    assert "the filter's map stands" in said[1]
    assert not (tmp_path / "robot1-filter.npz").exists()
    saved = LandmarkMap.load(tmp_path / "robot1.npz")
    assert "smoothed" not in saved.metadata and len(saved) == result.summary["robots"]["robot1"]["landmarks"]
    assert "robot1: map not smoothed: past the smoothing's cap" in format_summary(result.summary)


@pytest.mark.slow
def test_without_smooth_no_reading_is_kept_and_the_summary_has_no_smoothing(tmp_path):
    mission = Mission(_config(tmp_path, robots=1, seconds=2.0))
    result = mission.run()
    assert mission.robots[0].onboard.core.readings is None and mission.robots[0].onboard.core.frames > 0
    assert "smoothed" not in result.summary and "smoothing" not in result.summary["robots"]["robot1"]
    assert not (tmp_path / "robot1-filter.npz").exists()
