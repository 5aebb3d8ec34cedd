"""``p3at fuse`` of two maps made from one data set's log over overlapping times is refused (session 48, helper E's
walkthrough): two seeds of ``p3at slam dataset ... --robot 1`` gave only a note ("several maps name the same
robot") and a merge whose covariances were halved on no new evidence, since the maps share their sightings and
odometry. Two maps of one robot from different logs, or from disjoint times of one log, still fuse."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.cli import main


def _map(path, dataset: str | None, times: tuple[float, float], seed: int) -> str:
    rng = np.random.default_rng(seed)
    n = 30
    positions = np.column_stack([rng.uniform(-5, 5, (n, 2)), np.zeros(n)])
    trajectory = np.column_stack([np.linspace(*times, 20), np.zeros((20, 3))])
    metadata = {} if dataset is None else {"dataset": dataset}
    LandmarkMap(positions=positions + rng.normal(0, 0.01, (n, 3)), covariances=np.tile(np.eye(3) * 1e-4, (n, 1, 1)),
                descriptors=rng.normal(size=(n, 8)), robot="robot1", trajectory=trajectory,
                metadata=metadata).save(path)
    return str(path)


@pytest.mark.parametrize(("spans", "refused"), [
    (((0.0, 600.0), (0.0, 600.0)), True),      # two seeds of the whole log
    (((0.0, 600.0), (300.0, 900.0)), True),    # overlapping windows: the readings of 300-600 s in both
    (((0.0, 300.0), (400.0, 900.0)), False),   # disjoint windows: no reading shared
])
def test_maps_of_one_log_over_overlapping_times_are_refused(tmp_path, capsys, spans, refused):
    a = _map(tmp_path / "a.npz", "MRCLAM_Dataset2/Robot1", spans[0], 1)
    b = _map(tmp_path / "b.npz", "MRCLAM_Dataset2/Robot1", spans[1], 2)
    status = main(["fuse", a, b, "--out", str(tmp_path / "m.npz")])
    err = capsys.readouterr().err
    said = "are maps of the same log (MRCLAM_Dataset2/Robot1) over overlapping times" in err
    assert said == refused, err
    if refused:
        assert status == 2 and err.count("\n") == 1 and not (tmp_path / "m.npz").exists(), err


def test_maps_of_different_logs_are_not_refused_for_it(tmp_path, capsys):
    a = _map(tmp_path / "a.npz", "MRCLAM_Dataset2/Robot1", (0.0, 600.0), 1)
    b = _map(tmp_path / "b.npz", "MRCLAM_Dataset2/Robot2", (0.0, 600.0), 2)
    c = _map(tmp_path / "c.npz", None, (0.0, 600.0), 3)
    main(["fuse", a, b, c, "--out", str(tmp_path / "m.npz")])
    assert "same log" not in capsys.readouterr().err
