"""benchmarks/mrclam_turn_onsets: the measurement that found MRCLAM's heading error at mid-turn stalls, not at the
starts of turns, must be able to see an acceleration limit and a stall when a log has one (synthetic logs made
with them), and must find robot 1's stall at its first sighting in the real data."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.mrclam_turn_onsets import analyse
from estimation.datasets import RangeBearingLog, read_mrclam
from estimation.datasets.landmark_log import integrate_velocities

DT = 0.02
LAG_SAMPLES = 8          # the robot follows its commands 0.16 s late


def _commands(rng, duration_s=400.0):
    """Commanded (t, v, ω) at 50 Hz: turns on the spot of ±0.4 rad/s and straight runs at 0.1 m/s, 1-4 s each,
    separated by stops."""
    t = np.arange(0.0, duration_s, DT)
    v, w = np.zeros(len(t)), np.zeros(len(t))
    k = 50
    while k < len(t):
        n = int(rng.uniform(1.0, 4.0) / DT)
        if rng.random() < 0.6:
            w[k:k + n] = rng.choice([-0.4, 0.4])
        else:
            v[k:k + n] = 0.1
        k += n + int(rng.uniform(0.5, 2.0) / DT)
    return t, v, w


def _rate_limited(w, alpha):
    out, state = np.empty_like(w), 0.0
    for k, target in enumerate(w):
        state += float(np.clip(target - state, -alpha * DT, alpha * DT))
        out[k] = state
    return out


def _log(t, v, w_cmd, w_true):
    late = lambda x: np.r_[np.zeros(LAG_SAMPLES), x[:-LAG_SAMPLES]]   # noqa: E731
    return RangeBearingLog("synthetic", integrate_velocities(t, v, w_cmd), np.zeros(0), np.zeros(0), np.zeros(0),
                           np.zeros(0, np.int64), ground_truth=integrate_velocities(t, late(v), late(w_true)))


def test_an_acceleration_limit_is_recovered():
    t, v, w = _commands(np.random.default_rng(1))
    result = analyse(_log(t, v, w, _rate_limited(w, 2.0)), 1)
    assert result["lag_s"] == pytest.approx(LAG_SAMPLES * DT + 0.1, abs=0.06)   # a pure delay absorbs half the ramp
    best = min(result["fit_alpha"], key=lambda f: f["rms_rad"])
    assert 1.5 <= best["alpha"] <= 3.0
    assert best["lag_s"] == pytest.approx(LAG_SAMPLES * DT, abs=0.03)
    assert best["rms_rad"] < 0.5 * result["fit_pure_delay"]["rms_rad"]
    # a start loses ω²/(2α) = 0.04 rad, which is ω times the delay's extra ω/(2α) = 0.1 s: the calibrated delay
    # takes it back on average, and only the ramp's shape is left (what the α fit above sees)
    windows = result["windows"]["0.5"]
    assert abs(windows["start"]["mean_signed_rad"]) < 0.01 and abs(windows["stop"]["mean_signed_rad"]) < 0.01
    assert result["stalls"]["count"] == 0


def test_stalls_are_found_and_no_acceleration_limit_is_invented():
    rng = np.random.default_rng(2)
    t, v, w = _commands(rng)
    w_true = w.copy()
    steady = np.flatnonzero((np.abs(w) > 0.3) & (np.abs(np.r_[w[25:], np.zeros(25)] - w) < 1e-9)
                            & (np.abs(np.r_[np.zeros(25), w[:-25]] - w) < 1e-9))
    onsets = []
    for k in rng.permutation(steady):
        if all(abs(k - o) > 200 for o in onsets) and len(onsets) < 5:
            onsets.append(int(k))
    for k in onsets:
        w_true[k:k + 20] = 0.0           # the robot stops turning for 0.4 s: 0.16 rad lost
    result = analyse(_log(t, v, w, w_true), 1)
    stalls = result["stalls"]
    assert stalls["count"] == len(onsets) == 5
    assert stalls["lost_median_rad"] == pytest.approx(0.16, abs=0.04)
    best = min(result["fit_alpha"], key=lambda f: f["rms_rad"])
    assert best["rms_rad"] > 0.9 * result["fit_pure_delay"]["rms_rad"]
    assert result["windows"]["1.0"]["stall"]["share_sq_error"] > 0.5


def test_real_dataset2_robot1_stalls_at_its_first_sighting(mrclam_dir):
    log = read_mrclam(mrclam_dir, 1, until=120.0)
    stalls = analyse(log, 1)["stalls"]["within_2s_of_first_sighting"]
    assert len(stalls) == 1 and 0.05 < stalls[0][2] < 0.2 and 0.0 <= stalls[0][0] - log.sighting_times[0] < 0.5
