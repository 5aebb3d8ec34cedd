"""The front end on rendered frames of the virtual head against the renderer's true 3-D points."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mocks.stereo_head.renderer", reason="the virtual stereo head renderer is not installed")

EVAL_SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "eval_frontend.py"


def load_evaluation():
    """The evaluation script (benchmarks/ is not a package on the test path), loaded from its file."""
    spec = importlib.util.spec_from_file_location("eval_frontend", EVAL_SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_rendered_frames_are_accurate_and_the_covariances_consistent():
    # two poses of the office building (~1.5 s of rendering); docs/frontend.md reports six
    result = load_evaluation().evaluate_rendered(poses=((3.0, 5.0, 0.0), (10.0, 4.5, -0.3)), seed=1)
    assert result["points"] > 150
    assert result["disparity_within_1px"] >= 0.93
    assert result["median_3d_error_m"] <= 0.06
    assert result["median_relative_3d_error"] <= 0.02
    # most points inside the 95 % χ² bounds: the covariance is not over-confident
    assert result["nees3_below_chi2_95"] >= 0.9
    assert result["disparity_nees_below_chi2_95"] >= 0.9
    # nor grossly pessimistic: inlier disparity errors are of the order of σ_d = 0.3 px
    assert 0.1 <= result["rms_disparity_error_px_inliers"] <= 0.35
    assert np.isfinite(result["median_depth_m"])
