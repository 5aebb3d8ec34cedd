"""The self-calibration's uncertainty from its residuals' time structure (estimation.calibration_uncertainty) and the
MRCLAM benchmark's refusals (benchmarks.mrclam_calibration_uncertainty). Simulated logs: no data set needed."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from benchmarks.mrclam_calibration_uncertainty import main as benchmark_main
from estimation.calibration_uncertainty import (
    andrews_bandwidth,
    clustered_covariance,
    corrected,
    influences,
    newey_west_covariance,
    null_draws,
    per_second,
)
from estimation.camera_calibration import self_calibrate
from tests.estimation.test_camera_calibration import _log, _model, _most_sighted_pair

TRUE = np.array([-0.08, 0.97, 0.0, 0.0, 0.01])   # _log's camera: a, b0, b1, b2, psi


@functools.cache
def _calibrated(correlation: float, keep: bool = True):
    """Seed 3's 12-minute log, its sightings' errors AR(1) along each pass with ``correlation`` (the model told
    nothing of it), self-calibrated with its most-sighted pair taped (the odometry's scale free, as on MRCLAM)."""
    log = _log(np.random.default_rng(3), correlation=correlation)
    return log, self_calibrate(log, _model(), known_distances=(_most_sighted_pair(log),), keep_solution=keep)


def _newey_west_sigma_a(log, calibration) -> float:
    found = influences(log, calibration)
    series = per_second(found)
    bandwidth = max(andrews_bandwidth(series[:, j]) for j in range(4))
    kappa = null_draws(found, lambda draw: newey_west_covariance(found, bandwidth, draw))
    return float(np.sqrt(corrected(newey_west_covariance(found, bandwidth), kappa)[0, 0]))


def test_keeping_the_solution_changes_nothing_of_the_estimate():
    log, kept = _calibrated(0.0)
    _, plain = _calibrated(0.0, keep=False)
    assert plain.solution is None and kept.solution is not None
    np.testing.assert_array_equal(kept.values, plain.values)
    np.testing.assert_array_equal(kept.covariance, plain.covariance)
    assert kept.as_dict() == plain.as_dict()


def test_the_influences_sum_to_zero_and_their_information_is_the_printed_covariance():
    log, calibration = _calibrated(0.0)
    found = influences(log, calibration)
    se = np.sqrt(np.diag(found.laplace))
    # the score is 0 at the joint solution: the influences of all rows cancel (to the solve's tolerance)
    assert np.all(np.abs(found.rows.sum(axis=0)) < 1e-3 * se)
    # the inverse information's calibration block is what the calibration prints (a, b0, b1, psi; the scale apart)
    printed = calibration.covariance[np.ix_(found.free[:4], found.free[:4])]
    np.testing.assert_allclose(found.laplace[:4, :4], printed, rtol=1e-8)
    assert np.all(np.isfinite(found.times[:-1])) and np.isnan(found.times[-1])   # the tape's row has no time


def test_with_the_model_s_own_errors_the_corrected_sandwich_agrees_with_the_printed_sigma():
    log, calibration = _calibrated(0.0)
    ratio = _newey_west_sigma_a(log, calibration) / float(np.sqrt(calibration.covariance[0, 0]))
    assert 0.7 < ratio < 1.4


def test_errors_correlated_along_each_pass_that_the_model_does_not_know_widen_the_range_offset_s_sigma():
    """ρ 0.9 along each pass, the model told 0: the printed σ of a is 2.1 times too small on this log (a 1.9 of it
    off the simulated camera); the time-clustered sandwich gives a σ 2.1 times larger (a 0.9 of it off)."""
    log, calibration = _calibrated(0.9)
    printed = float(np.sqrt(calibration.covariance[0, 0]))
    sigma = _newey_west_sigma_a(log, calibration)
    error = abs(calibration.values[0] - TRUE[0])
    assert sigma > 1.5 * printed
    assert error > 1.5 * printed and error < 1.5 * sigma


def test_blocks_the_length_of_the_log_see_nothing_and_single_rows_see_every_residual():
    log, calibration = _calibrated(0.0)
    found = influences(log, calibration, draws=2)
    whole = clustered_covariance(found, 1e6)           # one block: the influences cancel, only the tape's share
    np.testing.assert_allclose(whole, found.lengths, atol=1e-6 * float(np.max(np.diag(found.laplace))))
    rows = clustered_covariance(found, 0.0)
    assert np.all(np.diag(rows)[:4] > np.diag(found.lengths)[:4])


def test_andrews_bandwidth_grows_with_the_series_correlation():
    rng = np.random.default_rng(0)
    white = rng.standard_normal(2000)
    slow = np.zeros(2000)
    for i in range(1, 2000):
        slow[i] = 0.9 * slow[i - 1] + white[i]
    assert andrews_bandwidth(white) < 3.0
    assert andrews_bandwidth(slow) > 20.0
    assert andrews_bandwidth(np.zeros(10)) == 0.0


def test_the_influences_need_the_solution_kept():
    log, calibration = _calibrated(0.0, keep=False)
    with pytest.raises(ValueError, match="keep_solution=True"):
        influences(log, calibration)


@pytest.mark.parametrize("argv, complaint", [
    (["--robot", "6"], "--robot must be 1-5"),
    (["--data", "/nonexistent/mrclam"], "no such folder"),
])
def test_the_benchmark_refuses_what_it_cannot_measure(argv, complaint, capsys):
    assert benchmark_main(argv) == 2
    assert complaint in capsys.readouterr().err
