"""One bearing error per image in a data set run's smoother (``run_landmark_log(..., image_timing=True)``, ``p3at
slam dataset --image-timing``; estimation.image_timing): on a log whose images are exposed anywhere in the period
about their stamps while the robot turns, and whose first image (the map's frame) is stale by half a period, the
landmarks are within their NEES bound with the term and far outside it without; the option is refused where there
is no smoother."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import RangeBearingLog
from estimation.fastslam import range_bearing_config
from estimation.geometry import wrap_angle
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from tests.estimation.frame_helpers import seen_from, unicycle

from .conftest import run_cli

ANGLES = np.linspace(0, 2 * np.pi, 12, endpoint=False)
LANDMARKS = np.column_stack([4.0 * np.cos(ANGLES), 1.5 + 4.0 * np.sin(ANGLES)])
PERIOD, BEARING_SIGMA, TURN_RATE = 0.24, 0.003, 0.5
NOISE = NoiseModel(OdometryNoise(0.003, 0.0087, 1e-4),
                   RangeBearingNoise(0.03, 0.0, BEARING_SIGMA, fov_rad=1.0, max_range_m=6.0))


def _log(seed: int) -> RangeBearingLog:
    """A robot still for 0.5 s turns on the spot once at 0.5 rad/s, then drives a 1.5 m circle at 0.2 m/s, inside a
    ring of 12 landmarks; an image every 0.24 s of the landmarks within 0.5 rad and 6 m (two on average), exposed at
    an instant uniform over the period about its stamp (the first, at 1 s while turning, half a period before it:
    stale), its bearings with noise of σ 0.003 rad. Exact odometry and ranges."""
    rng = np.random.default_rng(seed)
    dt = 0.02
    t = np.arange(0.0, 40.0, dt)
    turn_end = 0.5 + 2 * np.pi / TURN_RATE
    w = np.where(t < 0.5, 0.0, np.where(t < turn_end, TURN_RATE, 0.2 / 1.5))
    v = np.where(t < turn_end, 0.0, 0.2)
    x, y, theta = unicycle(v, w, dt)
    poses = np.column_stack([t, x, y, wrap_angle(theta)])
    times, ids, ranges, bearings = [], [], [], []
    for j, stamp in enumerate(np.arange(1.0, 39.0, PERIOD)):
        offset = -PERIOD / 2 if j == 0 else rng.uniform(-PERIOD / 2, PERIOD / 2)
        k = int(round((stamp + offset) / dt))
        r, b = seen_from(LANDMARKS, x[k], y[k], theta[k])
        seen = np.flatnonzero((np.abs(b) < 0.5) & (r < 6))
        times += [stamp] * len(seen)
        ids += list(seen)
        ranges += list(r[seen])
        bearings += list(b[seen] + BEARING_SIGMA * rng.standard_normal(len(seen)))
    return RangeBearingLog("synthetic-image-timing", poses, np.array(times), np.array(ranges), np.array(bearings),
                           np.array(ids, np.int64), poses, np.arange(len(LANDMARKS)), LANDMARKS)


def _run(log: RangeBearingLog, image_timing: bool):
    return run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(0), noise=NOISE,
                            association="id", robot="robot1", smooth=True, image_timing=image_timing)


@pytest.mark.parametrize("seed", [0, 1])
def test_images_exposed_off_their_stamps_while_turning_are_held_by_the_shared_error(seed):
    log = _log(seed)
    plain, shared = _run(log, False), _run(log, True)
    p, s = plain.metrics, shared.metrics
    # without the term the first image's common error (ω P/2 = 0.06 rad) turns the frame by many of its σ
    assert abs(p["landmark_frame_error"][2]) > 10 * p["landmark_frame_sd"][2]
    assert p["landmark_nees_within_bound"] < 0.5
    # with it, the frame's σ holds it and the landmarks are within their bound
    assert abs(s["landmark_frame_error"][2]) < 3 * s["landmark_frame_sd"][2]
    assert s["landmark_nees_within_bound"] >= 0.9
    assert s["smoother_image_timing_sigma_s"] == pytest.approx(PERIOD / np.sqrt(12), rel=1e-9)
    assert s["smoother_image_bearing_sd_max_rad"] == pytest.approx(TURN_RATE * PERIOD / np.sqrt(12), rel=0.05)
    assert not any(key.startswith("smoother_image_") for key in p)


def test_the_shared_error_needs_the_smoother():
    with pytest.raises(ValueError, match="it needs smoothing"):
        run_landmark_log(_log(0), range_bearing_config(n_particles=10), np.random.default_rng(0), noise=NOISE,
                         association="id", image_timing=True)


@pytest.mark.parametrize("options", [["--association", "unknown"], ["--no-smooth"],
                                     ["--association", "unknown", "--chain"]])
def test_the_command_refuses_the_shared_error_without_the_smoother_before_reading_anything(tmp_path, options):
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "nothing-here"), "--robot", "1", "--out",
                               str(tmp_path / "map.npz"), "--image-timing", *options)
    assert status == 2 and out == ""
    assert err.startswith("p3at slam dataset: --image-timing") and "it needs --association id and the smoother" in err
    assert not (tmp_path / "map.npz").exists()
