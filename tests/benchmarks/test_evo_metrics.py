"""benchmarks/evo_metrics.rpe on a path shorter than its distance: no pair to compare, so nan, not evo's exception
(``eval_mrclam --until 20`` stopped on evo's FilterException: 'delta = 1.0 (m) produced an empty index list')."""
from __future__ import annotations

import math

import numpy as np

from benchmarks import evo_metrics


def _straight(length_m: float, poses: int = 50) -> np.ndarray:
    t = np.linspace(0.0, 10.0, poses)
    return np.column_stack([t, np.linspace(0.0, length_m, poses), np.zeros(poses), np.zeros(poses)])


def test_a_path_shorter_than_delta_has_no_relative_error():
    truth = _straight(0.4)
    estimate = truth + [0.0, 0.01, 0.0, 0.0]
    scores = evo_metrics.evaluate(truth, estimate, delta=1.0)
    assert math.isnan(scores["rpe_translation_rmse_m"]) and math.isnan(scores["rpe_rotation_rmse_rad"])
    assert abs(scores["ate_rmse_m"] - 0.01) < 1e-9


def test_a_path_longer_than_delta_is_scored():
    truth = _straight(5.0)
    estimate = truth.copy()
    estimate[:, 1] *= 1.1                              # 10 % too long: 0.1 m per metre travelled
    scores = evo_metrics.rpe(truth, estimate, delta=1.0)
    assert abs(scores["rpe_translation_rmse_m"] - 0.1) < 0.02 and scores["rpe_rotation_rmse_rad"] < 1e-9
