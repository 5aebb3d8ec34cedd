"""MRCLAM: is the fitted odometry model honest over long open paths? NEES of dead reckoning per horizon.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_odometry_horizons [--data DIR] [--robots 1 2 3 4 5]

Prints (docs/fastslam-history.md, "Session 22: the odometry model over long open paths (O)"):
1. per robot and horizon (5-600 s), with the model `p3at slam dataset` fits by default (DATASET_CALIBRATIONS, on the
   whole log), the NEES median of the dead-reckoned end pose (χ²₃: 2.37) and the fraction of windows within χ²₃'s
   95 % bound (``estimation.odometry_consistency``);
2. the research question: does a two-term model explain the growth? White (the fitted random walk, its variance ×
   α, ∝ path) plus systematic errors constant over a window (a translation scale σ_s, a heading change per metre
   σ_b, a turn scale σ_r: variance ∝ path²), fitted across horizons on the first half of each log (the random walk
   and the calibrations fitted on that half too) by matching the NEES medians to 2.37, and checked on the second
   half. Fitted per robot, and pooled over the five robots' first halves.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from estimation.datasets import read_mrclam
from estimation.noise_model import DATASET_CALIBRATIONS, estimate_noise
from estimation.odometry_consistency import (
    CHI2_3_95,
    CHI2_3_MEDIAN,
    HORIZONS_S,
    dead_reckoned_windows,
    nees,
    odometry_consistency,
)
from runtime.commands.options import positive_int

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
TERMS = ("white ×α", "σ_s (scale)", "σ_b (rad/m)", "σ_r (turn scale)")


def half(log, first: bool):
    """The log's first or second half in time (odometry, sightings and ground truth cut at the midpoint)."""
    mid = 0.5 * (log.ground_truth[0, 0] + log.ground_truth[-1, 0])

    def keep(t):
        return t <= mid if first else t >= mid

    s = keep(log.sighting_times)
    return replace(log, name=f"{log.name} ({'first' if first else 'second'} half)",
                   odometry=log.odometry[keep(log.odometry[:, 0])], sighting_times=log.sighting_times[s],
                   ranges=log.ranges[s], bearings=log.bearings[s], landmark_ids=log.landmark_ids[s],
                   ground_truth=log.ground_truth[keep(log.ground_truth[:, 0])])


def covariance(w, params: np.ndarray) -> np.ndarray:
    """The two-term model's covariance (W, 3, 3): α·(the random walk's) + Σ σ_k² j_k j_kᵀ (systematic terms)."""
    alpha, s2, b2, r2 = params
    out = alpha * w.covariance
    for var, j in ((s2, w.by_scale), (b2, w.by_heading_per_m), (r2, w.by_turn_scale)):
        out = out + var * j[:, :, None] * j[:, None, :]
    return out


def medians(windows_by_horizon, params) -> np.ndarray:
    return np.array([np.median(np.concatenate([nees(w, covariance(w, params)) for w in ws]))
                     for ws in windows_by_horizon])


def fit_two_term(windows_by_horizon) -> np.ndarray:
    """(α, σ_s², σ_b², σ_r²) whose NEES medians are nearest 2.37 (squared log ratio summed over the horizons)."""
    def cost(x):
        m = medians(windows_by_horizon, np.exp(x))
        return float(np.sum(np.log(m / CHI2_3_MEDIAN) ** 2))

    x0 = np.log([1.0, 0.02 ** 2, 0.01 ** 2, 0.01 ** 2])
    best = minimize(cost, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-5, "maxiter": 2000})
    return np.exp(best.x)


def scores(windows_by_horizon, params) -> list[tuple[float, float]]:
    out = []
    for ws in windows_by_horizon:
        v = np.concatenate([nees(w, covariance(w, params)) for w in ws])
        out.append((float(np.median(v)), float(np.mean(v < CHI2_3_95))))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DATA), help="MRCLAM data set 2 folder")
    parser.add_argument("--robots", type=positive_int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--section", choices=("all", "horizons", "two-term"), default="all")
    args = parser.parse_args(argv)
    if not Path(args.data).is_dir():
        print(f"no data set at {args.data}", file=sys.stderr)
        return 2
    logs = {r: read_mrclam(args.data, r) for r in args.robots}
    horizons = [f"{h:g} s" for h in HORIZONS_S]
    if args.section in ("all", "horizons"):
        print("1. The default model (DATASET_CALIBRATIONS, whole log): NEES median / % within χ²₃ 95 % per horizon")
        print("   robot  " + "  ".join(f"{h:>12}" for h in horizons))
        for r, log in logs.items():
            model = estimate_noise([log], **DATASET_CALIBRATIONS).model
            report = odometry_consistency([(log.odometry, log.ground_truth)], model)
            print(f"   {r:>5}  " + "  ".join(f"{h.nees_median:6.2f}/{100 * h.within_chi2_95:3.0f} %" for h in report))
    if args.section in ("all", "two-term"):
        print("2. Two-term model fitted on the first halves, checked on the second halves "
              "(NEES median / % within, per horizon)")
        first, second, pooled_first, pooled_second = {}, {}, [[] for _ in HORIZONS_S], [[] for _ in HORIZONS_S]
        for r, log in logs.items():
            a, b = half(log, True), half(log, False)
            model = estimate_noise([a], **DATASET_CALIBRATIONS).model
            first[r] = [[dead_reckoned_windows(a.odometry, a.ground_truth, model, h)] for h in HORIZONS_S]
            second[r] = [[dead_reckoned_windows(b.odometry, b.ground_truth, model, h)] for h in HORIZONS_S]
            for k in range(len(HORIZONS_S)):
                pooled_first[k] += first[r][k]
                pooled_second[k] += second[r][k]
        pooled = fit_two_term(pooled_first)
        print("   pooled fit: " + ", ".join(f"{name} {v:.4g}" for name, v in
                                            zip(TERMS, [pooled[0], *np.sqrt(pooled[1:])], strict=True)))
        print("   robot  model           " + "  ".join(f"{h:>12}" for h in horizons))
        white = np.array([1.0, 0.0, 0.0, 0.0])
        for r in logs:
            own = fit_two_term(first[r])
            print(f"   {r:>5}  own fit: " + ", ".join(f"{name} {v:.4g}" for name, v in
                                                    zip(TERMS, [own[0], *np.sqrt(own[1:])], strict=True)))
            for label, params in (("white (as fitted)", white), ("two-term, own", own), ("two-term, pooled", pooled)):
                print(f"   {r:>5}  {label:<17} " + "  ".join(f"{m:6.2f}/{100 * f:3.0f} %"
                                                          for m, f in scores(second[r], params)))
        for label, params in (("white (as fitted)", white), ("two-term, pooled", pooled)):
            print(f"   all    {label:<17} " + "  ".join(f"{m:6.2f}/{100 * f:3.0f} %"
                                                      for m, f in scores(pooled_second, params)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
