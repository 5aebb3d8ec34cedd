"""A data set run's recording shows what the command warns about: the warnings as WARN text under the map, the
sighting an unchecked frame rests on (estimation.frame_reliability) drawn where it was taken, with its ray to its
landmark, and a chain's unchecked namings (estimation.naming_reliability) as the stretch of path their sightings were
taken from. A run whose frame is checked draws no such sighting, and a run without warnings has no warnings panel."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimation.dataset_slam import run_landmark_log
from estimation.fastslam import range_bearing_config
from runtime.dataset_recording import record_dataset_run
from runtime.rerun_style import dataset_blueprint
from tests.datasets.turning_start import NOISE
from tests.datasets.turning_start import turning_start_log as _log

from .rerun_helpers import blueprint_views, entity_rows


def _recorded(tmp_path, first_landmarks: int, warnings: list[str]):
    log = _log(first_landmarks)
    run = run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(0), noise=NOISE,
                           association="id", robot="robot1", smooth=True)
    rrd = tmp_path / f"first-{first_landmarks}.rrd"
    record_dataset_run(str(rrd), run, log, "robot1", warnings)
    return run, rrd


def test_the_sighting_an_unchecked_frame_rests_on_is_drawn_with_its_ray_and_the_warnings_are_logged(tmp_path):
    warnings = ["the map's frame rests on single sightings: …", "only 60 % of the landmarks are within …"]
    run, rrd = _recorded(tmp_path, 1, warnings)
    assert run.metrics["frame_reliability_unchecked"]
    events = entity_rows(rrd, "mission/events")
    assert [text for row in events for text in row["TextLog:text"]] == warnings
    assert {level for row in events for level in row["TextLog:level"]} == {"WARN"}
    [tie] = entity_rows(rrd, "map/robot1/frame_tie")
    sighting = run.metrics["frame_reliability_heading_sighting"]            # 1.00 s, the lone first bearing
    k = int(np.argmin(np.abs(run.estimated_trajectory[:, 0] - sighting["time_s"])))
    start = np.asarray(run.metrics["true_start_pose"])
    assert np.allclose(start, 0.0)                                          # the log's truth starts at the origin
    np.testing.assert_allclose(tie["Points2D:positions"][0], run.estimated_trajectory[k, 1:3], atol=1e-5)
    assert f"landmark {sighting['landmark']}" in tie["Points2D:labels"][0]
    assert "bearing" in tie["Points2D:labels"][0]
    [ray] = entity_rows(rrd, "map/robot1/frame_tie/ray")
    external = list(run.map.metadata["external_ids"])
    landmark = run.map.positions[external.index(sighting["landmark"]), :2]
    np.testing.assert_allclose(ray["LineStrips2D:strips"][0][-1], landmark, atol=1e-5)


def test_a_checked_frame_draws_no_sighting_and_no_warning_means_no_warnings_panel(tmp_path):
    run, rrd = _recorded(tmp_path, 3, [])
    assert not run.metrics["frame_reliability_unchecked"]
    assert entity_rows(rrd, "map/robot1/frame_tie") == []
    assert entity_rows(rrd, "mission/events") == []


@pytest.mark.parametrize("warned", [False, True])
def test_the_warnings_panel_is_in_the_layout_only_when_there_are_warnings(warned):
    layout = dataset_blueprint("robot1", warned=warned)
    views = [view.class_identifier for view in blueprint_views(layout.root_container)]
    assert ("TextLog" in views) == warned


def test_an_unchecked_naming_is_drawn_along_the_path_its_sightings_were_taken_from(tmp_path):
    """The figures as naming_metrics gives them (the chain's; here on a known-ID run, whose recording is the same
    code): the path between the run's first and last sighting, labelled at its start; an unbounded move says so."""
    log = _log(3)
    run = run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(0), noise=NOISE,
                           association="id", robot="robot1", smooth=True)
    times = run.estimated_trajectory[:, 0]
    namings = [{"name": 4, "start_s": float(times[5]), "end_s": float(times[9]), "sightings": 7,
                "frame_effect_sd": [19.1, 3.0, 2.0]},
               {"name": 2, "start_s": float(times[20]), "end_s": float(times[20]), "sightings": 1,
                "frame_effect_sd": [None, None, 8.0]}]
    rrd = tmp_path / "named.rrd"
    record_dataset_run(str(rrd), dataclasses.replace(run, metrics={**run.metrics, "untestable_namings": namings}),
                       log, "robot1", ["the map rests on namings nothing checks: …"])
    [first] = entity_rows(rrd, "map/robot1/naming_tie/0")
    np.testing.assert_allclose(first["LineStrips2D:strips"][0], run.estimated_trajectory[5:10, 1:3], atol=1e-5)
    [start] = entity_rows(rrd, "map/robot1/naming_tie/0/start")
    label = start["Points2D:labels"][0]
    assert label.startswith("these 7 sightings (") and " named 4: " in label and "(19.1 σ of the frame)" in label
    [second] = entity_rows(rrd, "map/robot1/naming_tie/1/start")
    assert "the frame floats without it" in second["Points2D:labels"][0]
    assert entity_rows(rrd, "map/robot1/frame_tie") == []                   # the frame itself is checked here
