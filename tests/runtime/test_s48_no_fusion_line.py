"""The mission summary's fusion line when there is no alignment to show says why, from the robots' maps.

Session 48 (D): ``p3at demo --realtime --seconds 15`` on a loaded machine (both virtual heads dropped nearly every
frame) ended with two robots' maps of 0 landmarks each (robot2's never published: no frame processed) and said
"Fusion: fewer than two maps, nothing to fuse." beside a table of two maps."""
from __future__ import annotations

from runtime.report import format_summary


def _robot(landmarks: int, frames: int) -> dict:
    return {"landmarks": landmarks, "frames_processed": frames, "frames_dropped": 0, "frames_without_odometry": 0,
            "final_position_error": 1.3, "odometry_position_error": None, "ms_per_frame": {}}


def _summary(robots: dict, failures: list | None = None) -> dict:
    # as runtime/mission.py builds it when the mission made no fusion (its final fusion None)
    return {"robots": robots, "duration": 15.05, "clock": "wall", "wall_seconds": 15.3, "realtime_factor": 0.98,
            "camera": "mock", "particles": 100, "seed": 0, "failures": failures or [], "fusion": None}


def _fusion_line(summary: dict) -> str:
    lines = format_summary(summary).splitlines()
    return " ".join(line.strip() for line in lines[[k for k, line in enumerate(lines)
                                                     if line.startswith("Fusion")][0]:])


def test_two_empty_maps_are_said_to_be_empty_with_their_counts():
    line = _fusion_line(_summary({"robot1": _robot(0, 1), "robot2": _robot(0, 0)}))
    assert line == ("Fusion: no alignment: every map is empty (robot1: 0 landmarks from 1 frame; robot2: 0 landmarks "
                    "from 0 frames).")


def test_one_map_with_landmarks_beside_an_empty_one():
    line = _fusion_line(_summary({"robot1": _robot(120, 60), "robot2": _robot(0, 2)}))
    assert line.startswith("Fusion: no alignment: only robot1's map holds landmarks (robot1: 120 landmarks from 60 "
                           "frames; robot2: 0 landmarks from 2 frames)")


def test_a_failed_fusion_stage_is_named_and_one_robot_still_has_nothing_to_fuse():
    failed = [{"robot": "mission", "stage": "fusion", "t": 20.0, "error": "ValueError: boom"}]
    assert "the fusion failed" in _fusion_line(_summary({"robot1": _robot(120, 60), "robot2": _robot(90, 60)},
                                                        failed))
    assert _fusion_line(_summary({"robot1": _robot(120, 60)})) == "Fusion: fewer than two maps, nothing to fuse."
