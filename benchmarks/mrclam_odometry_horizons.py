"""MRCLAM: is the fitted odometry model honest over long open paths? NEES of dead reckoning per horizon.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_odometry_horizons [--data DIR] [--robots 1 2 3 4 5]
        [--section all|horizons|two-term|halves|drift] [--without-command]

Every window is scored with the log's commanded velocity, as ``p3at slam noise`` scores a model (session 42 (B2)):
the model's stall after the command's dips (``stall_sigma_s``, a default calibration since session 42) adds its
variance to the steps that hold a dip, as the filter adds it to its increments. ``--without-command``: the windows
without it, the random walk alone, as the tables of sessions 22 (O) and 37 were made (docs/fastslam.md's table of
the default model per horizon is ``--section horizons --without-command``).

Prints (docs/fastslam-history.md, "Session 22: the odometry model over long open paths (O)"):
1. per robot and horizon (5-600 s), with the model `p3at slam dataset` fits by default (DATASET_CALIBRATIONS, on the
   whole log), the NEES median of the dead-reckoned end pose (χ²₃: 2.37) and the fraction of windows within χ²₃'s
   95 % bound (``estimation.odometry_consistency``);
2. the research question: does a two-term model explain the growth? White (the fitted random walk, its variance ×
   α, ∝ path) plus systematic errors constant over a window (a translation scale σ_s, a heading change per metre
   σ_b, a turn scale σ_r, a heading change per second σ_ω: variance ∝ path²), fitted across horizons on the first
   half of each log, pooled (the random walk and the calibrations fitted on that half too), so that each horizon's
   NEES median is 2.37 and 95 % of its windows are within the bound (see fit_two_term); checked on the second
   halves. Beside it the model as fitted on the whole logs, the first halves and the second halves;
3. what does not carry from one half to the other: the second halves scored with their own model, with the first
   halves', and with the calibrations (scales, heading bias, lag, forward deficit) of one and the variances
   (random walk, turns' inflation) of the other;
4. a drifting heading bias: the random walk plus a heading bias per metre that is a first-order Gauss–Markov process
   (stationary σ_b, correlation time τ; ``dead_reckoned_windows(heading_drift=...)``), (σ_b, τ) chosen on a grid by
   the same criterion on the first halves, scored on the second halves and on the whole logs (their own models).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from estimation.datasets import read_mrclam
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise
from estimation.noise_model import OdometryNoise
from estimation.odometry_consistency import (
    CHI2_3_95,
    CHI2_3_MEDIAN,
    HORIZONS_S,
    dead_reckoned_windows,
    nees,
    odometry_consistency,
)
from estimation.odometry_response import with_drive_response
from runtime.commands.options import non_negative_float, positive_int

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
TERMS = ("white ×α", "σ_s (scale)", "σ_b (rad/m)", "σ_r (turn scale)", "σ_ω (rad/s)")
WHITE = np.array([1.0, 0.0, 0.0, 0.0, 0.0])
DRIFT_SIGMAS = (0.04, 0.08, 0.12, 0.16, 0.24)    # rad/m
DRIFT_TAUS = (10.0, 30.0, 100.0, 300.0)          # s
VARIANCES = ("xy_var_per_m", "theta_var_per_rad", "theta_var_per_m", "turn_xy_inflation", "heading_drift_sigma_per_m",
             "heading_drift_tau_s")
CALIBRATIONS = tuple(f.name for f in fields(OdometryNoise) if f.name not in VARIANCES)


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
    alpha, s2, b2, r2, o2 = params
    out = alpha * w.covariance
    for var, j in ((s2, w.by_scale), (b2, w.by_heading_per_m), (r2, w.by_turn_scale), (o2, w.by_heading_per_s)):
        out = out + var * j[:, :, None] * j[:, None, :]
    return out


def medians(windows_by_horizon, params) -> np.ndarray:
    return np.array([np.median(np.concatenate([nees(w, covariance(w, params)) for w in ws]))
                     for ws in windows_by_horizon])


def fit_two_term(windows_by_horizon, terms=(True, True, True, True)) -> np.ndarray:
    """(α, σ_s², σ_b², σ_r², σ_ω²) (the systematic terms not in ``terms`` held at 0) that make every horizon's
    windows look like χ²₃: the sum over horizons of log(median / 2.37)² + ((share within the 95 % bound − 0.95) /
    0.05)², by Nelder-Mead on the logarithms (a local search: compare subsets, not only the full set)."""
    mask = np.asarray(terms, bool)

    def params(x):
        p = np.zeros(5)
        p[0] = np.exp(x[0])
        p[1:][mask] = np.exp(x[1:])
        return p

    def cost(x):
        total = 0.0
        for ws in windows_by_horizon:
            v = np.concatenate([nees(w, covariance(w, params(x))) for w in ws])
            total += np.log(np.median(v) / CHI2_3_MEDIAN) ** 2 + ((np.mean(v < CHI2_3_95) - 0.95) / 0.05) ** 2
        return float(total)

    x0 = np.log([1.0, *np.array([0.02 ** 2, 0.01 ** 2, 0.01 ** 2, 0.001 ** 2])[mask]])
    best = minimize(cost, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-5, "maxiter": 3000})
    return params(best.x)


def _describe(p) -> str:
    return ", ".join(f"{name} {v:.3g}" for name, v in zip(TERMS, [p[0], *np.sqrt(p[1:])], strict=True))


def _row(label, windows_by_horizon, p) -> str:
    return f"   {label:<24} " + "  ".join(f"{m:6.2f}/{100 * f:3.0f} %" for m, f in scores(windows_by_horizon, p))


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
    parser.add_argument("--section", choices=("all", "horizons", "two-term", "halves", "drift"), default="all")
    parser.add_argument("--without-command", action="store_true",
                        help="score the windows without the log's commanded velocity: no stall variance after its "
                             "dips, the random walk alone (the tables of sessions 22 and 37)")
    parser.add_argument("--response-time", type=non_negative_float, default=0.0, metavar="T",
                        help="integrate the commanded velocities through a first-order response of time constant T "
                             "s (estimation.odometry_response) before everything; 0, the default: as read")
    args = parser.parse_args(argv)

    def command(log):
        """The log's command rows for the model's stall term, or None (--without-command)."""
        return None if args.without_command else log.velocities

    if not Path(args.data).is_dir():
        print(f"no data set at {args.data}", file=sys.stderr)
        return 2
    logs = {r: with_drive_response(read_mrclam(args.data, r), args.response_time) for r in args.robots}
    horizons = [f"{h:g} s" for h in HORIZONS_S]
    if args.section in ("all", "horizons"):
        print("1. The default model (DATASET_CALIBRATIONS, whole log): NEES median / % within χ²₃ 95 % per horizon")
        print("   robot  " + "  ".join(f"{h:>12}" for h in horizons))
        for r, log in logs.items():
            model = estimate_noise([log], **DATASET_CALIBRATIONS).model
            report = odometry_consistency([(log.odometry, log.ground_truth)], model, commands=[command(log)])
            print(f"   {r:>5}  " + "  ".join(f"{h.nees_median:6.2f}/{100 * h.within_chi2_95:3.0f} %" for h in report))
    if args.section in ("all", "two-term"):
        print("2. Two-term models fitted on the first halves (pooled), NEES median / % within per horizon on the first "
              "halves (in sample) and the second halves (out of sample)")
        print("   " + " " * 24 + " " + "  ".join(f"{h:>12}" for h in horizons))
        whole, first, second = ([[] for _ in HORIZONS_S] for _ in range(3))
        for log in logs.values():
            model = estimate_noise([log], **DATASET_CALIBRATIONS).model
            a, b = half(log, True), half(log, False)
            model_a = estimate_noise([a], **DATASET_CALIBRATIONS).model    # the calibrations of the first half
            for k, h in enumerate(HORIZONS_S):
                whole[k].append(dead_reckoned_windows(log.odometry, log.ground_truth, model, h, command=command(log)))
                first[k].append(dead_reckoned_windows(a.odometry, a.ground_truth, model_a, h, command=command(a)))
                second[k].append(dead_reckoned_windows(b.odometry, b.ground_truth, model_a, h, command=command(b)))
        print(_row("whole logs: as fitted", whole, WHITE))
        print(_row("first: as fitted", first, WHITE))
        print(_row("second: as fitted", second, WHITE))
        for label, terms in (("white × α", (False,) * 4), ("+ heading/m", (False, True, False, False)),
                             ("+ heading/s", (False, False, False, True)),
                             ("+ scale + heading/m", (True, True, False, False)), ("+ all four", (True,) * 4)):
            p = fit_two_term(first, terms)
            print(f"   {label}: {_describe(p)}")
            print(_row("  first (in sample)", first, p))
            print(_row("  second (out of sample)", second, p))
    if args.section in ("all", "halves"):
        print("3. The second halves scored with (NEES median / % within, per horizon)")
        print("   " + " " * 24 + " " + "  ".join(f"{h:>12}" for h in horizons))
        scored = {label: [[] for _ in HORIZONS_S] for label in ("own model", "the first half's",
                                                                "first's calibration", "first's variances")}
        for r, log in logs.items():
            a, b = half(log, True), half(log, False)
            model_a, model_b = (estimate_noise([x], **DATASET_CALIBRATIONS).model for x in (a, b))
            oa, ob = model_a.odometry, model_b.odometry
            print(f"   robot {r}: " + ", ".join(f"{name} {getattr(oa, name):.4g} -> {getattr(ob, name):.4g}"
                                                for name in ("translation_scale", "rotation_scale",
                                                             "heading_bias_per_m", "lag_s")))
            mixed_calibration = replace(model_b, odometry=replace(ob, **{k: getattr(oa, k) for k in CALIBRATIONS}))
            mixed_variances = replace(model_b, odometry=replace(ob, **{k: getattr(oa, k) for k in VARIANCES}))
            for label, model in zip(scored, (model_b, model_a, mixed_calibration, mixed_variances), strict=True):
                for k, h in enumerate(HORIZONS_S):
                    scored[label][k].append(dead_reckoned_windows(b.odometry, b.ground_truth, model, h,
                                                                  command=command(b)))
        for label, windows in scored.items():
            print(_row(label, windows, WHITE))
    if args.section in ("all", "drift"):
        print("4. A drifting heading bias (Gauss–Markov) on the random walk, fitted on the first halves")
        print("   " + " " * 24 + " " + "  ".join(f"{h:>12}" for h in horizons))
        parts = {"first": [], "second": [], "whole": []}
        for log in logs.values():
            a, b = half(log, True), half(log, False)
            model_a = estimate_noise([a], **DATASET_CALIBRATIONS).model
            parts["first"].append((a, model_a))
            parts["second"].append((b, model_a))
            parts["whole"].append((log, estimate_noise([log], **DATASET_CALIBRATIONS).model))

        def drift_windows(part, drift):
            return [[dead_reckoned_windows(x.odometry, x.ground_truth, m, h, heading_drift=drift, command=command(x))
                     for x, m in part] for h in HORIZONS_S]

        def cost(windows) -> float:
            return float(sum(np.log(m / CHI2_3_MEDIAN) ** 2 + ((f - 0.95) / 0.05) ** 2
                             for m, f in scores(windows, WHITE)))

        tried = sorted((cost(drift_windows(parts["first"], (sigma, tau))), sigma, tau)
                       for sigma in DRIFT_SIGMAS for tau in DRIFT_TAUS)
        print("   grid (σ_b rad/m, τ s: cost on the first halves): "
              + ", ".join(f"({sigma:g}, {tau:g}): {c:.1f}" for c, sigma, tau in tried[:6]) + ", ...")
        for _, sigma, tau in tried[:2]:
            for name in ("first", "second", "whole"):
                print(_row(f"σ_b {sigma:g}, τ {tau:g}: {name}", drift_windows(parts[name], (sigma, tau)), WHITE))
        print(_row("no drift: second", drift_windows(parts["second"], None), WHITE))
    return 0


if __name__ == "__main__":
    sys.exit(main())
