"""``p3at slam noise``: a noise model fitted from logs with ground truth, or a camera calibrated from its own log
(``--self-calibrate``; the parser is in :mod:`.slam`)."""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from estimation.errors import EstimationError
from runtime.commands.options import check_output_apart, check_output_file
from runtime.json_output import json_text


def no_sensor_fit(model, logs) -> str | None:
    """Why a fitted noise model has no sensor part (None when it has one): too few sightings of landmarks whose
    positions the data set knows. `slam noise` wrote such a model without a word (exit 0) and `slam dataset --noise`
    then refused it; `slam dataset` said its own fitted model 'has no [range_bearing] section'."""
    if model.range_bearing is not None:
        return None
    known = sum(int(np.isin(log.landmark_ids, log.truth_ids).sum()) for log in logs)
    return (f"too few sightings of landmarks with known positions to fit the sensor noise ({known} in the log): the "
            "model would lack its [range_bearing] part, which slam dataset needs")


MIN_WINDOW_INTERVALS = 3   # odometry intervals a residual window must span at the least


def _window_problem(window: float, logs) -> str | None:
    """Why ``--window`` is too short for these logs (None when it is not): a window must span MIN_WINDOW_INTERVALS
    of a log's odometry intervals (their median), else its windows hold one row or none and the fit is of nothing
    (session 23: ``--window 1e-300`` wrote a model, exit 0)."""
    for log in logs:
        stamps = log.odometry[:, 0]
        interval = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.0
        if window < MIN_WINDOW_INTERVALS * interval:
            return (f"--window {window:g}: shorter than {MIN_WINDOW_INTERVALS} odometry intervals of {log.name} "
                    f"({interval:.3g} s, the median); give at least {MIN_WINDOW_INTERVALS * interval:.3g} s (default "
                    "5 s)")
        span = float(stamps[-1] - stamps[0]) if len(stamps) > 1 else 0.0
        if window > span:   # no window fits; 1e308 overflowed the window's count of intervals (exit 70)
            return f"--window {window:g}: longer than the odometry of {log.name} ({span:.3g} s); give a shorter one"
    return None


_FIT_FLAGS = ("heading_bias", "range_calibration", "odometry_lag", "turn_translation", "turn_variance",
              "heading_drift", "time_variance", "calibration_per_log", "command_stall")


def _self_calibration_problem(args: argparse.Namespace) -> str | None:
    """What makes ``slam noise``'s options meaningless together, in one line (None: nothing)."""
    if not args.self_calibrate:
        if args.known_distance:
            return "--known-distance is a length for --self-calibrate: it needs --self-calibrate"
        if args.estimate_sigmas:
            return ("--estimate-sigmas estimates the sigmas beside --self-calibrate's calibration: it needs "
                    "--self-calibrate (a fit against the truth estimates them anyway)")
        return "--noise is the model --self-calibrate starts from: it needs --self-calibrate" if args.noise else None
    if args.noise is None:
        return "--self-calibrate needs --noise FILE: the odometry and sensor sigmas it keeps"
    if len(set(args.robot)) != 1:
        return "--self-calibrate calibrates one robot's camera: give one --robot"
    given = [f"--{name.replace('_', '-')}" for name in _FIT_FLAGS if getattr(args, name)]
    if args.window is not None:
        given.append("--window")
    if given:
        return f"--self-calibrate estimates the camera alone (the rest is --noise's): {', '.join(given)} do not apply"
    if args.truth_heading is not None:
        return "--self-calibrate reads no ground truth: --truth-heading does not apply"
    if args.barcodes not in (None, "table"):
        return (f"--self-calibrate reads no ground truth, and --barcodes {args.barcodes} checks the table against it: "
                "give --barcodes table (its default)")
    return None


def run_noise(args: argparse.Namespace) -> int:
    from dataclasses import asdict, replace

    from estimation.datasets import read_mrclam
    from estimation.noise_estimation import estimate_noise
    from estimation.odometry_consistency import CHI2_3_95, CHI2_3_MEDIAN, fit_keys, odometry_consistency

    if (problem := _self_calibration_problem(args)) is not None:
        print(f"p3at slam noise: {problem}", file=sys.stderr)
        return 2
    if args.self_calibrate:
        return _self_calibrate(args)
    args.window = 5.0 if args.window is None else args.window
    try:
        check_output_file(args.out)
        _check_toml_out(args.out)
        check_output_apart(args.out, folders={"data set": args.folder})   # its tables stay as they are
        logs = [read_mrclam(args.folder, robot, barcodes=args.barcodes or "verified",
                            truth_heading=args.truth_heading or "mocap") for robot in dict.fromkeys(args.robot)]
        short = _window_problem(args.window, logs)
        if short is not None:
            raise ValueError(short)
        estimate = estimate_noise(logs, window_s=args.window, heading_bias=args.heading_bias,
                                  range_calibration=args.range_calibration, odometry_lag=args.odometry_lag,
                                  turn_translation=args.turn_translation, turn_variance=args.turn_variance,
                                  heading_drift=args.heading_drift, time_variance=args.time_variance,
                                  calibration_per_log=args.calibration_per_log, command_stall=args.command_stall,
                                  platform="iRobot Create (MRCLAM; odometry = commanded velocities)")
        if (problem := no_sensor_fit(estimate.model, logs)) is not None:
            raise ValueError(problem)
        # does the fitted random walk hold beyond its window? dead reckoning's NEES per horizon, into [fit] too (the
        # logs' command for the model's stall after its dips, when it has that term)
        consistency = odometry_consistency([(log.odometry, log.ground_truth) for log in logs], estimate.model,
                                           commands=[log.velocities for log in logs])
        aligned = {"truth_heading": "travel"} if args.truth_heading == "travel" else {}
        model = replace(estimate.model, fit={**estimate.model.fit, **fit_keys(consistency), **aligned})
        model.save(args.out)
    except (ValueError, OSError, EstimationError) as e:
        print(f"p3at slam noise: {e}", file=sys.stderr)
        return 2
    windows = [dict(window_s=w, xy_sigma_per_sqrt_m=a, theta_sigma_per_sqrt_rad=b, theta_sigma_per_sqrt_m=c)
               for w, a, b, c in estimate.odometry_by_window.tolist()]
    if args.json:
        print(json_text({"out": str(args.out), "robot": model.robot, "odometry": asdict(model.odometry),
                         "range_bearing": asdict(model.range_bearing) if model.range_bearing else None,
                         "fit": model.fit, "odometry_by_window": windows,
                         "odometry_consistency": [row.as_dict() for row in consistency]}))
        return 0
    o, rb = model.odometry, model.range_bearing
    print(f"slam noise: {model.robot}")
    print(f"  odometry: σ_xy {math.sqrt(o.xy_var_per_m):.4f} m/√m, σ_θ {math.sqrt(o.theta_var_per_rad):.4f} rad/√rad "
          f"+ {math.sqrt(o.theta_var_per_m):.4f} rad/√m (windows of {args.window:g} s); scales: translation "
          f"{o.translation_scale:.4f}, rotation {o.rotation_scale:.4f}")
    if args.heading_bias:
        se = model.fit.get("heading_bias_per_m_standard_error")
        print(f"  heading bias: {o.heading_bias_per_m:+.4f} rad/m ± {se:.4f} (standard error)" if se is not None
              else f"  heading bias: none ({model.fit.get('heading_bias_note', 'not fitted')})")
    if args.odometry_lag:
        print(f"  odometry lag: {o.lag_s:.2f} s (heading error per 0.25 s: "
              f"{model.fit.get('odometry_no_lag_heading_rms_rad', float('nan')):.4f} rad read as stamped, "
              f"{model.fit.get('odometry_lag_heading_rms_rad', float('nan')):.4f} rad read {o.lag_s:.2f} s earlier)"
              if "odometry_lag_note" not in model.fit else f"  odometry lag: none ({model.fit['odometry_lag_note']})")
    if args.turn_translation:
        se = model.fit.get("forward_deficit_per_rad_standard_error", float("nan"))
        print(f"  forward deficit: {o.forward_deficit_per_rad:.4f} m/rad ± {se:.4f} (standard error; {args.window:g} s "
              "windows' "
              f"displacement error {model.fit.get('forward_deficit_none_displacement_rms_m', float('nan')):.4f} m "
              f"RMS with one translation scale, {model.fit.get('forward_deficit_displacement_rms_m', float('nan')):.4f}"
              f" m with the deficit)" if "forward_deficit_note" not in model.fit
              else f"  forward deficit: none ({model.fit['forward_deficit_note']})")
    if args.turn_variance:
        print(f"  x/y variance in turns: × {o.turn_xy_inflation:.2f} (over "
              f"{model.fit.get('turn_xy_inflation_turns', 0)} turns)" if "turn_xy_inflation_note" not in model.fit
              else f"  x/y variance in turns: × 1 ({model.fit['turn_xy_inflation_note']})")
    if args.heading_drift:
        print(f"  drifting heading bias: σ_b {o.heading_drift_sigma_per_m:.2f} rad/m, τ {o.heading_drift_tau_s:g} s "
              f"(cost {model.fit['heading_drift_cost']:.1f} against {model.fit['heading_drift_cost_without']:.1f} "
              f"without)" if o.heading_drift_sigma_per_m > 0 else "  drifting heading bias: none (no drift made the "
              "dead reckoning more consistent)")
    if args.time_variance:
        print(f"  heading variance per second: {o.theta_var_per_s:.3g} rad²/s (σ_θ {math.sqrt(o.theta_var_per_s):.4f} "
              "rad/√s, moving or not)")
    if args.command_stall:
        print(f"  stall after a dip of the command: σ {o.stall_sigma_s:.3f} s (variance "
              f"{model.fit['stall_variance_s2']:.4f} ± {model.fit['stall_variance_standard_error_s2']:.4f} s², "
              f"{model.fit['stall_dips_measured_heading']} + {model.fit['stall_dips_measured_travel']} of "
              f"{model.fit['stall_dips']} dips measured)" if "stall_note" not in model.fit
              else f"  stall after a dip of the command: none ({model.fit['stall_note']})")
    for row in windows:
        print(f"    at {row['window_s']:>4g} s windows: σ_xy {row['xy_sigma_per_sqrt_m']:.4f} m/√m, σ_θ "
              f"{row['theta_sigma_per_sqrt_rad']:.4f} rad/√rad + {row['theta_sigma_per_sqrt_m']:.4f} rad/√m")
    if consistency:
        print(f"  dead reckoning under this model over longer paths (NEES of the end pose; consistent: median "
              f"{CHI2_3_MEDIAN:.2f}, 95 % below {CHI2_3_95:.2f}):")
    for row in consistency:
        print(f"    {row.horizon_s:>4g} s: median {row.nees_median:5.2f}, {100 * row.within_chi2_95:5.1f} % within "
              f"({row.windows} windows, {row.independent} without overlap): {row.verdict}")
    if rb:
        print(f"  sensor: σ_r = {rb.range_sigma_m:.4f} m + {rb.range_sigma_per_m:.4f}·r, "
              f"σ_φ {rb.bearing_sigma_rad:.4f} rad, bearing offset {rb.bearing_offset_rad:+.4f} rad; "
              f"{100 * model.fit.get('sensor_outlier_fraction', 0.0):.1f} % outliers set aside")
    print(f"  written to {args.out}")
    return 0


def _known_text(known, calibration=None) -> str:
    """The known distances in words ('' if none): ', with ... taped' for the source, the map's fit with one."""
    if not known:
        return ""
    if calibration is None:
        return ", with " + ", ".join(f"{k.first}-{k.second} {k.metres:g} ± {k.sigma_m:g} m" for k in known) + " taped"
    return "".join(f" {k.first}-{k.second} {k.metres:g} ± {k.sigma_m:g} m (the map's {d:.4f} m)"
                   for k, d in zip(known, calibration.fitted_distances_m, strict=True))


def _sigmas_text(calibration, noise) -> str:
    """The estimated sensor sigmas in one line, with their standard errors and the given ones."""
    nc, rb = calibration.noise_components, noise.range_bearing
    root, se = nc.sigma_factors, nc.sigma_relative_errors
    return (f"  sensor sigmas (variance components of the residuals, marginal; correlations {rb.range_correlation:.2f}"
            f" / {rb.bearing_correlation:.2f} kept): range {rb.range_sigma_m * root[1]:.4f} m + "
            f"{rb.range_sigma_per_m * root[1]:.4f}·r (x {root[1]:.3f} ± {root[1] * se[1]:.3f} of the given "
            f"{rb.range_sigma_m:.4f} + {rb.range_sigma_per_m:.4f}·r), bearing {rb.bearing_sigma_rad * root[2]:.5f} ± "
            f"{rb.bearing_sigma_rad * root[2] * se[2]:.5f} rad (given {rb.bearing_sigma_rad:.4f}); redundancy "
            f"{nc.redundancies[1]:.0f} / {nc.redundancies[2]:.0f}, {nc.rounds} rounds")


def _check_toml_out(out) -> None:
    """ValueError (one line) when --out names one of the project's other files (runtime.commands.file_kinds)."""
    from runtime.commands.file_kinds import out_problem

    if (problem := out_problem(out, "noise model")) is not None:
        raise ValueError(problem)


def _self_calibrate(args: argparse.Namespace) -> int:
    """``slam noise --self-calibrate``: the camera's calibration without ground truth
    (estimation.camera_calibration)."""
    from estimation.camera_calibration import ESTIMATED, SIGMAS, KnownDistance, self_calibrate
    from estimation.datasets import read_mrclam
    from estimation.noise_model import NoiseModel

    try:
        check_output_file(args.out)
        _check_toml_out(args.out)
        check_output_apart(args.out, files={"--noise": args.noise}, folders={"data set": args.folder})
        noise = NoiseModel.load(args.noise)
        if noise.range_bearing is None:
            raise ValueError(f"{args.noise}: the noise model has no [range_bearing] section to calibrate")
        log = read_mrclam(args.folder, args.robot[0], barcodes="table")
        known = tuple(KnownDistance(*k) for k in args.known_distance)
        sigmas = args.estimate_sigmas
        calibration = self_calibrate(log, noise, known_distances=known,
                                     noise_components=("range", "bearing") if sigmas else ())
        model = None
        if calibration.problem is None:
            with_scale = "" if calibration.translation_scale is None else \
                "; estimated with the odometry translation scale, recorded in [fit]"
            if sigmas:
                with_scale += "; and the range and bearing sigmas, as variance components of its residuals"
            model = calibration.applied(
                noise, robot=log.name,
                source=f"camera calibration (range offset, scale, scale per radian, bearing offset{with_scale}"
                       f") self-calibrated by p3at slam "
                       f"noise --self-calibrate from {log.name}'s odometry and sightings associated by barcode, "
                       f"without its ground truth{_known_text(known)}; the rest from the model given "
                       f"({noise.robot}: {noise.source})")
            model.save(args.out)
    except (ValueError, OSError, EstimationError) as e:
        print(f"p3at slam noise: {e}", file=sys.stderr)
        return 2
    given = {k: float(getattr(noise.range_bearing, k)) for k in ESTIMATED}
    if args.json:
        print(json_text({"out": str(args.out) if model is not None else None, "robot": log.name,
                         "association": "barcode", "ground_truth_read": False, "noise": str(args.noise),
                         "calibration": calibration.as_dict(), "given": given,
                         "odometry_translation_scale": noise.odometry.translation_scale,
                         **({"sigmas": {k: getattr(model.range_bearing, k) for k in SIGMAS}}
                            if sigmas and model is not None else {})}))
    else:
        c, se = calibration, calibration.standard_errors
        print(f"slam noise --self-calibrate: {log.name} (sightings associated by barcode; the ground truth is not "
              f"read)")
        print(f"  camera: range r' = a + r (b0 + b1 phi + b2 phi^2): a {c.range_offset_m:+.4f} ± {se[0]:.4f} m, b0 "
              f"{c.range_scale:.4f} ± {se[1]:.4f}, b1 {c.range_scale_per_rad:+.4f} ± {se[2]:.4f} /rad; bearing offset "
              f"{c.bearing_offset_rad:+.4f} ± {se[4]:.4f} rad (standard errors; given: a "
              f"{given['range_offset_m']:+.4f}, b0 {given['range_scale']:.4f}, b1 "
              f"{given['range_scale_per_rad']:+.4f}, offset "
              f"{given['bearing_offset_rad']:+.4f}; b2 {c.range_scale_per_rad2:.4f}"
              + (f" kept from {args.noise})" if sigmas else f" and the sigmas kept from {args.noise})"))
        if sigmas:
            print(_sigmas_text(calibration, noise))
        print(f"  fit: {c.sightings} sightings ({c.outliers} set aside as outliers), {c.landmarks} landmarks, "
              f"{c.frames} frames, chi2/dof {c.chi2_per_dof:.2f}, {c.iterations} iterations; the calibrated range's "
              f"own sigma {c.range_sd_rms_m:.4f} m RMS against one sighting's {c.range_sigma_rms_m:.4f} m")
        if known:
            print(f"  known distances (taped, a factor on the two landmarks):{_known_text(known, calibration)}")
        if calibration.translation_scale is not None:
            print(f"  odometry translation scale {calibration.translation_scale:.4f} ± "
                  f"{calibration.translation_scale_standard_error:.4f} (estimated with the camera, so that the tape "
                  f"gives the map its scale; correlation with b0 "
                  f"{calibration.range_scale_translation_scale_correlation:+.2f}): recorded in [fit], the odometry "
                  f"kept at {noise.odometry.translation_scale:.4f} from {args.noise} (the estimate is biased by the "
                  "odometry's noise)")
        else:
            print(f"  b0 is relative to the odometry's scale (translation scale "
                  f"{noise.odometry.translation_scale:.4f} from {args.noise}): an odometry scale wrong by 1 % moves b0 "
                  "by 1 %, and the standard errors leave it out")
        print(f"  written to {args.out}" if model is not None
              else f"  not determined: {calibration.problem}; nothing written")
    if model is None:
        if not args.json:
            print(f"p3at slam noise: the camera's calibration is not determined on {log.name}: {calibration.problem}",
                  file=sys.stderr)
        return 1
    return 0
