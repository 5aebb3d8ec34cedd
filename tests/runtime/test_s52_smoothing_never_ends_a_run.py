"""The smoothing after the mission (the default of ``p3at demo`` / ``p3at run`` since session 51) never ends a robot's
run: whatever goes wrong in it, one line says why and the filter's map is the robot's map (docs/runtime.md, "the
smoothing never ends a mission"; ``Onboard.smooth_final_map``: "Never raises").

Two ways it could, found in session 52's review (D):

- the readings are kept frame by frame *during* the run (``ReadingsRecorder.add``, which with keyframes composes the
  odometry's covariance and matches descriptors on every frame), inside the SLAM stage: an error there ended the
  robot's SLAM stage, and so its mission, for the sake of a smoothing that would only have been refused;
- a smoothed map that its reader would refuse (a covariance that is not positive definite, a non-finite value) was
  taken as the robot's map: ``OUT/<robot>.npz`` was then not written and the mission failed at its map save, where
  the filter's map, a good one, was at hand.

Short one-robot missions (2 simulated seconds, the synthetic camera), as tests/runtime/test_mission_smooth.py's.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import runtime.onboard as onboard
from estimation.landmark_map import LandmarkMap
from estimation.stereo_readings import ReadingsRecorder
from runtime.mission import Mission, MissionConfig
from runtime.report import format_summary


def _mission(out, events: list[str]) -> Mission:
    return Mission(MissionConfig(robots=1, seconds=2.0, seed=5, camera="synthetic", camera_rate=10.0, particles=30,
                                 fusion_interval=5.0, out=out, rerun="none", odometry="realistic", smooth=True),
                   events=events.append)


def _filter_map_stands(out, result, reason: str) -> None:
    """The mission ended well, its map file the filter's, the summary and one line saying why it was not smoothed."""
    assert not result.failures, result.failures
    figures = result.summary["robots"]["robot1"]["smoothing"]
    assert figures["smoothed"] is False and reason in figures["reason"] and "\n" not in figures["reason"]
    assert result.summary["smoothed"] is False
    saved = LandmarkMap.load(out / "robot1.npz")
    assert "smoothed" not in saved.metadata and len(saved) == result.summary["robots"]["robot1"]["landmarks"] > 0
    assert not (out / "robot1-filter.npz").exists()
    assert f"robot1: map not smoothed: {figures['reason']}" in " ".join(format_summary(result.summary).split())


@pytest.mark.slow
def test_an_error_while_keeping_the_readings_does_not_end_the_run(tmp_path, monkeypatch):
    keep = ReadingsRecorder.add
    calls = []

    def fails_at_the_fifth_frame(self, t, odometry_pose, observations):
        calls.append(t)
        if len(calls) == 5:
            raise FloatingPointError("a stand-in for anything the keyframe rule's arithmetic raises\non two lines")
        return keep(self, t, odometry_pose, observations)

    monkeypatch.setattr(ReadingsRecorder, "add", fails_at_the_fifth_frame)
    events: list[str] = []
    mission = _mission(tmp_path, events)
    result = mission.run()
    reason = ("keeping the readings failed at frame 5: FloatingPointError: a stand-in for anything the keyframe "
              "rule's arithmetic raises on two lines")
    _filter_map_stands(tmp_path, result, reason)
    core = mission.robots[0].onboard.core
    assert len(calls) == 5 and core.frames > 5        # nothing more was kept; the filter went on
    said = [e for e in events if "keeping the readings failed" in e]
    assert len(said) == 2, events                     # once when it happened, once at the end
    assert said[0] == f"robot1: smoothing: {reason}; the filter's map will stand"
    assert said[1] == f"robot1: the map was not smoothed: {reason}; the filter's map stands"


@pytest.mark.slow
def test_a_smoothed_map_its_reader_would_refuse_is_not_taken(tmp_path, monkeypatch):
    smooth = onboard.smoothed_map

    def not_positive_definite(*args, **kwargs):
        out = smooth(*args, **kwargs)
        m = out.landmark_map
        covariances = m.covariances.copy()
        covariances[0] = np.diag([1e-4, 1e-4, -1e-4])
        m.covariances = covariances
        return dataclasses.replace(out, landmark_map=m)

    monkeypatch.setattr(onboard, "smoothed_map", not_positive_definite)
    events: list[str] = []
    result = _mission(tmp_path, events).run()
    _filter_map_stands(tmp_path, result, "the smoothed map would not be readable: ")
    said = [e for e in events if "the map was not smoothed" in e]
    assert len(said) == 1 and "covariances" in said[0], events


@pytest.mark.slow
def test_a_smoothing_that_raises_is_said_in_one_line(tmp_path, monkeypatch):
    """An error raised by the smoothing whose message runs over several lines (numpy's and scipy's sometimes do) is
    said in one line, in the event and the summary, as every other reason."""
    def raises(*args, **kwargs):
        raise np.linalg.LinAlgError("first line of it\n  and a second")

    monkeypatch.setattr(onboard, "smoothed_map", raises)
    events: list[str] = []
    result = _mission(tmp_path, events).run()
    _filter_map_stands(tmp_path, result, "the smoothing failed: LinAlgError: first line of it and a second")
    said = [e for e in events if "the map was not smoothed" in e]
    assert len(said) == 1 and "\n" not in said[0], events
