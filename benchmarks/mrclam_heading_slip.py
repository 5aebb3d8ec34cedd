"""MRCLAM's heading odometry when turning on the spot: is there an error per radian turned that the smoother's
per-metre heading drift does not carry? (session 29, C)

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_heading_slip [--robots 1,2,3,4,5] [--slip 0.3 10] [--slip 0.2 10]
        [--all-turns] [--json]

For each robot: its noise model (``estimate_noise(**DATASET_CALIBRATIONS)``, the one every MRCLAM run uses), the
calibrated odometry's heading increments over the filter's frame interval (0.25 s, the odometry read ``lag_s``
earlier) against Vicon's, e = Δθ_true − Δθ_odometry. The steps are classed by the odometry: *in place* (turning,
|Δθ| > 0.0025 rad, with less than ``IN_PLACE_M_PER_RAD`` (0.1 m) travel per radian: the smoother's class), *arc*
(turning otherwise). Printed:

- gains: Σ true turn / Σ odometry turn, in place and in arcs, left and right apart (1: the calibration holds);
- per horizon (1-60 s, a window starting every 1 s): the share of windows whose heading error is within χ²₁ 95 %
  of the smoother's model (the white random walk, ``theta_var_per_rad``·|Δθ| + ``theta_var_per_m``·d, plus the
  Gauss–Markov heading bias per metre σ_b 0.16 rad/m, τ 10 s that mrclam_constellation smooths with), all windows
  and those whose turning is mostly in place, and the median z² of all (χ²₁: 0.45; below: conservative); with each
  ``--slip`` (σ rad/rad, τ s) the same with the smoother's per-radian slip (``HeadingDrift.sigma_per_rad``: a
  Gauss–Markov c_k multiplying |Δθ_k| of the steps in place) added to the model (``--all-turns``: of every step);
- the worst 40 s windows (z of the heading error, the time, Σ|Δθ|, net Δθ).

Windows touching a step whose heading error exceeds 0.5 rad (Vicon glitches) are left out. Ground truth here only
measures the odometry's error: nothing a map is built from.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import json  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.eval_mrclam import DATA  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.geometry import between, wrap_angle  # noqa: E402
from estimation.landmark_smoother import IN_PLACE_M_PER_RAD  # noqa: E402
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise  # noqa: E402
from runtime.commands.options import positive_float  # noqa: E402

STEP_S = 0.25                    # the filter's frame interval: the smoother's increments
HORIZONS_S = (1, 2, 5, 10, 20, 30, 60)
DRIFT = (0.16, 10.0)             # mrclam_constellation's --drift default (σ_b rad/m, τ s)
MIN_TURN_RAD = 0.0025            # a step turning less is not turning (0.01 rad/s)
GLITCH_RAD = 0.5                 # a heading error beyond this in one step is Vicon's, not the odometry's
CHI2_1_95 = 3.841
DEFAULT_SLIPS = ((0.2, 10.0), (0.3, 10.0))


def heading_steps(log, model) -> dict[str, np.ndarray]:
    """The log's steps of STEP_S: times, heading error e, odometry distance d and turn Δθ, the white variance."""
    o = model.odometry
    t0 = max(log.ground_truth[0, 0], log.odometry[0, 0]) + 1.0
    t1 = min(log.ground_truth[-1, 0], log.odometry[-1, 0]) - 1.0
    t = np.arange(t0, t1, STEP_S)
    odometry = log.odometry_pose(model.odometry_times(t))
    increments = model.calibrate_increments(between(odometry[:-1], odometry[1:]))
    true = between(log.true_pose(t[:-1]), log.true_pose(t[1:]))
    turn, distance = increments[:, 2], np.hypot(increments[:, 0], increments[:, 1])
    variance = o.theta_var_per_rad * np.abs(turn) + o.theta_var_per_m * distance + 1e-8   # + the filter's floor
    return {"t": t[:-1], "e": wrap_angle(true[:, 2] - turn), "d": distance, "turn": turn, "var": variance}


def window_sums(x: np.ndarray, n: int) -> np.ndarray:
    """Σ of x over every window of n consecutive steps."""
    return np.convolve(x, np.ones(n), "valid")


def gauss_markov_sums(x: np.ndarray, n: int, tau_s: float) -> np.ndarray:
    """xᵀKx over every window of n consecutive steps, K_ij = exp(−|i − j|·STEP_S/τ): a unit Gauss–Markov process's
    variance of Σ_k x_k g_k over the window."""
    decay = np.exp(-STEP_S / tau_s)
    out = np.zeros(len(x) - n + 1)
    starts = np.arange(len(out))
    for lag in range(n):
        cumulative = np.concatenate([[0.0], np.cumsum(x[:len(x) - lag] * x[lag:])])
        out += (cumulative[starts + n - lag] - cumulative[starts]) * decay ** lag * (1 if lag == 0 else 2)
    return out


def classes(steps: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(usable, in place, arc) step masks."""
    turn, d = steps["turn"], steps["d"]
    usable = np.abs(steps["e"]) < GLITCH_RAD
    turning = np.abs(turn) > MIN_TURN_RAD
    in_place = turning & (d < IN_PLACE_M_PER_RAD * np.abs(turn))
    return usable, in_place & usable, turning & ~in_place & usable


def gains(steps: dict) -> dict:
    usable, in_place, arc = classes(steps)
    out = {}
    for name, mask in (("in_place", in_place), ("arc", arc)):
        for side, sign in (("left", 1.0), ("right", -1.0)):
            m = mask & (np.sign(steps["turn"]) == sign)
            out[f"{name}_{side}_gain"] = float(np.sum(steps["turn"][m] + steps["e"][m]) / np.sum(steps["turn"][m]))
            out[f"{name}_{side}_turn_rad"] = float(np.abs(steps["turn"][m]).sum())
    return out


def horizons(steps: dict, slip: tuple[float, float] | None, all_turns: bool = False) -> dict:
    """Per horizon: windows, share within χ²₁ 95 %, median z², and the same for the mostly-in-place windows."""
    usable, in_place, _ = classes(steps)
    e = np.where(usable, steps["e"], 0.0)
    turn, d = np.abs(steps["turn"]), steps["d"]
    slipping = turn if all_turns else np.where(d < IN_PLACE_M_PER_RAD * turn, turn, 0.0)   # as the smoother's slip
    out = {}
    for h in HORIZONS_S:
        n = int(round(h / STEP_S))
        total = functools.partial(window_sums, n=n)
        variance = total(steps["var"]) + DRIFT[0] ** 2 * gauss_markov_sums(d, n, DRIFT[1])
        if slip is not None:
            variance = variance + slip[0] ** 2 * gauss_markov_sums(slipping, n, slip[1])
        z2 = total(e) ** 2 / variance
        turned = total(turn)
        keep = (total((~usable).astype(float)) == 0) & ((turned > 0.1) | (total(d) > 0.1))
        keep &= np.arange(len(keep)) % int(round(1.0 / STEP_S)) == 0
        mostly = keep & (total(turn * in_place) > 0.5 * turned) & (turned > 0.1)
        out[h] = {"windows": int(keep.sum()), "within": float(np.mean(z2[keep] < CHI2_1_95)),
                  "median_z2": float(np.median(z2[keep])), "in_place_windows": int(mostly.sum()),
                  "in_place_within": float(np.mean(z2[mostly] < CHI2_1_95)) if mostly.any() else float("nan")}
    return out


def worst_windows(steps: dict, horizon_s: float = 40.0, count: int = 3) -> list[dict]:
    usable, _, _ = classes(steps)
    e = np.where(usable, steps["e"], 0.0)
    n = int(round(horizon_s / STEP_S))
    total = functools.partial(window_sums, n=n)
    variance = total(steps["var"]) + DRIFT[0] ** 2 * gauss_markov_sums(steps["d"], n, DRIFT[1])
    z = np.where(total((~usable).astype(float)) == 0, total(e) / np.sqrt(variance), 0.0)
    picked: list[int] = []
    for i in np.argsort(-np.abs(z)):
        if all(abs(i - j) > n for j in picked):
            picked.append(int(i))
        if len(picked) == count:
            break
    return [{"start_s": float(steps["t"][i]), "z": float(z[i]), "error_rad": float(total(e)[i]),
             "turned_rad": float(total(np.abs(steps["turn"]))[i]), "net_turn_rad": float(total(steps["turn"])[i]),
             "travel_m": float(total(steps["d"])[i])} for i in picked]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--slip", type=positive_float, nargs=2, action="append", metavar=("RAD_PER_RAD", "S"),
                        help="a heading slip per radian (σ, τ) to add to the model; repeatable "
                             "(default 0.2 10, 0.3 10)")
    parser.add_argument("--all-turns", action="store_true", help="the slip multiplies every turn, not only those on "
                                                                     "the spot (not the smoother's model: to compare)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    slips = [tuple(s) for s in (args.slip or DEFAULT_SLIPS)]
    if any(not (sigma >= 0 and tau > 0) for sigma, tau in slips):
        parser.error("--slip: σ must be ≥ 0 and τ > 0")
    if not os.path.isdir(args.data):
        print(f"mrclam_heading_slip: no data set at {args.data}", file=sys.stderr)
        return 2
    rows = []
    for robot in (int(r) for r in args.robots.split(",")):
        log = read_mrclam(args.data, robot)
        steps = heading_steps(log, estimate_noise([log], **DATASET_CALIBRATIONS).model)
        row = {"robot": robot, "gains": gains(steps), "model": horizons(steps, None),
               "slips": {f"{s:g} {t:g}": horizons(steps, (s, t), args.all_turns) for s, t in slips},
               "worst_40s": worst_windows(steps)}
        rows.append(row)
        if not args.json:
            _print_row(row)
    if args.json:
        print(json.dumps(rows))
    return 0


def _print_row(row: dict) -> None:
    g = row["gains"]
    print(f"robot {row['robot']}: gains in place left {g['in_place_left_gain']:.2f} ({g['in_place_left_turn_rad']:.0f} "
          f"rad), right {g['in_place_right_gain']:.2f} ({g['in_place_right_turn_rad']:.0f} rad); arcs left "
          f"{g['arc_left_gain']:.2f}, right {g['arc_right_gain']:.2f}")
    for label, table in [("white + drift", row["model"])] + [(f"+ slip {k}", v) for k, v in row["slips"].items()]:
        print(f"  {label:16s} within χ²₁ 95 % (all / mostly in place): " + "  ".join(
            f"{h}s {c['within']:.2f}/{c['in_place_within']:.2f}" for h, c in table.items())
              + "; median z² " + "/".join(f"{c['median_z2']:.2f}" for c in table.values()))
    print("  worst 40 s: " + "; ".join(f"{w['start_s']:.0f} s z {w['z']:+.1f} ({w['error_rad']:+.2f} rad, Σ|Δθ| "
                                       f"{w['turned_rad']:.1f}, net {w['net_turn_rad']:+.1f}, {w['travel_m']:.1f} m)"
                                       for w in row["worst_40s"]), flush=True)


if __name__ == "__main__":
    sys.exit(main())
