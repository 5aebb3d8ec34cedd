"""The layout of a data set run (``p3at slam dataset --rerun``): with ground truth, the map beside the pose NEES; a log
without ground truth gets no NEES plot (it would stay empty) and a map title that says the run is not scored instead
of naming a grey true path that is not there. The run's own recording, end to end, on the synthetic log."""
from __future__ import annotations

import shutil

from runtime.rerun_style import dataset_blueprint
from tests.datasets.conftest import run_cli, write_mrclam
from tests.datasets.test_no_ground_truth import TRUTH_FILES, _noise

from .rerun_helpers import blueprint_views, entity_rows


def _views(blueprint) -> dict[str, list[str]]:
    views: dict[str, list[str]] = {}
    for view in blueprint_views(blueprint.root_container):
        views.setdefault(view.class_identifier, []).append(str(view.name))
    return views


def test_a_scored_run_shows_the_nees_and_the_true_path_an_unscored_one_says_why_not():
    scored, unscored = _views(dataset_blueprint("robot1")), _views(dataset_blueprint("robot1", scored=False))
    assert len(scored["TimeSeries"]) == 1 and "ground truth" in scored["TimeSeries"][0]
    assert [n for n in scored["2D"] if "grey: ground truth" in n]
    assert "TimeSeries" not in unscored
    assert [n for n in unscored["2D"] if "no ground truth: not scored" in n]
    assert not [n for name in unscored.values() for n in name if "grey: ground truth" in n]
    travel = _views(dataset_blueprint("robot1", truth_heading="travel"))
    assert [n for n in travel["2D"] if "grey: ground truth, its heading on the direction of travel" in n]
    assert not [n for n in scored["2D"] if "direction of travel" in n]


def test_a_run_without_truth_is_recorded_with_the_unscored_layout_and_one_with_truth_with_the_scored(
        tmp_path, monkeypatch):
    import runtime.dataset_recording as recording_module

    layouts = []

    def recorded(robot, **kwargs):
        layouts.append(kwargs["scored"])
        return dataset_blueprint(robot, **kwargs)

    monkeypatch.setattr(recording_module, "dataset_blueprint", recorded)
    write_mrclam(tmp_path / "with", seconds=20.0)
    shutil.copytree(tmp_path / "with", tmp_path / "without")
    for name in TRUTH_FILES:
        (tmp_path / "without" / name).unlink(missing_ok=True)
    for folder in ("with", "without"):
        recording = tmp_path / f"{folder}.rrd"
        status, _, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / folder), "--robot", "1", "--out",
                                 str(tmp_path / f"{folder}.npz"), "--particles", "5", "--noise", str(_noise(tmp_path)),
                                 "--barcodes", "table", "--rerun", str(recording))
        assert status == 0, err
        assert bool(entity_rows(recording, "plots/robot1/pose_nees")) == (folder == "with")
    assert layouts == [True, False]
