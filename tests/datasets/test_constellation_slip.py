"""benchmarks/mrclam_constellation --slip: a state smoothed with the heading slip per radian turned on the spot is
kept and read back whole, and is refused by a run without the slip (its meta's drift differs)."""
from __future__ import annotations

import numpy as np
import pytest

from .test_constellation import _robot2


def test_a_state_with_the_slip_reloads_to_the_same_solution_and_a_run_without_it_refuses_it(tmp_path):
    from benchmarks.mrclam_constellation import _drift_meta, load_saved_state, load_state, save_state, state_path
    from estimation.landmark_smoother import HeadingDrift, joint_landmark_covariance
    from estimation.named_smoothing import MergeRound, smooth_named

    log, noise, config, plain = _robot2(until=900.0)          # its wiggle on the spot: 779-817 s
    slip = HeadingDrift(plain.sigma_per_m, plain.tau_s, sigma_per_rad=0.3)
    names = np.asarray(log.landmark_ids, np.int64).copy()
    named, solution = smooth_named(log, names, noise, config, heading_drift=slip, path_step_s=0.25)
    assert solution.turn_biases is not None and np.any(solution.turn_biases != 0)
    path = state_path(tmp_path, log, 0, "round1")
    save_state(path, MergeRound([], 0.0, 0.0, True, names, named, solution),
               {"robot": log.name, "drift": _drift_meta(slip), "path_step_s": 0.25, "round": 1})
    state, meta = load_saved_state(path, log, noise, config)
    assert meta["drift"] == [plain.sigma_per_m, plain.tau_s, 0.3]
    np.testing.assert_array_equal(state.solution.turn_biases, solution.turn_biases)
    np.testing.assert_allclose(joint_landmark_covariance(state.named.problem, state.solution),
                               joint_landmark_covariance(named.problem, solution), rtol=1e-12)
    with pytest.raises(ValueError, match="drift"):
        load_state(path, log, noise, config, plain, 0.25)
    assert _drift_meta(plain) == [plain.sigma_per_m, plain.tau_s]       # states made before the slip still load
