"""MRCLAM: can a smoothed map tell from its own residuals that its noise model was fitted on other robots?

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_residual_correlation [--data DIR] [--robots 1 2 3 4 5]

Each robot's whole log is smoothed with known association (the barcodes; the chain's heading drift and slip) twice:
with the model fitted on its own log (``estimate_noise([log], **DATASET_CALIBRATIONS)``, in sample) and with the
model fitted on the other four robots' logs pooled. Printed per robot and model: the lag-1 correlation of the
solution's normalised range and bearing residuals between consecutive sightings of one landmark (pooled over the
landmarks; no truth read), beside the model's own ``range_correlation`` / ``bearing_correlation`` (fitted against
the truth), and χ² per degree of freedom.

Session 37 (lead; docs/fastslam-history.md): the range residuals separate the two models (in sample 0.07–0.19, the
other robots' 0.54–0.77), but never exceed the model's own ρ (the pooled model carries ρ_r 0.82–0.90), so a check
"residuals more correlated than the model says" flags none: the pooled model is loose, not overconfident per
sighting. Not built into the product. Seconds of CPU per robot.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimation.chain_settings import ChainSettings
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.landmark_smoother import normalised_residuals
from estimation.named_smoothing import smooth_named
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise
from runtime.commands.options import positive_int

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"


def lag1_within_groups(values: np.ndarray, groups: np.ndarray) -> float:
    """The lag-1 correlation of ``values`` (N,) between consecutive entries of one group (``groups`` (N,); the
    order within a group is the given one), each group about its own mean, pooled over the groups."""
    products = squares = 0.0
    for group in np.unique(groups):
        series = values[groups == group]
        series = series - series.mean()
        products += float(np.sum(series[1:] * series[:-1]))
        squares += float(np.sum(series * series))
    return products / squares if squares > 0 else float("nan")


def barcode_names(log) -> np.ndarray:
    """Each sighting's landmark index (0..L−1) by its barcode's post, −1 for a barcode without a true post."""
    known = np.isin(log.landmark_ids, log.truth_ids)
    return np.where(known, np.searchsorted(np.sort(log.truth_ids), log.landmark_ids), -1)


def residual_row(log, noise) -> dict:
    """The known-ID smoothing of ``log`` with ``noise``: its residuals' lag-1 correlations and the model's."""
    named, solution = smooth_named(log, barcode_names(log), noise, range_bearing_config(n_particles=10),
                                   heading_drift=ChainSettings().heading_drift)
    _, sightings, _ = normalised_residuals(named.problem, solution)
    kept = solution.inliers
    landmark = named.problem.landmark_index[kept]
    sensor = noise.range_bearing
    return {"range_lag1": lag1_within_groups(sightings[kept, 0], landmark),
            "bearing_lag1": lag1_within_groups(sightings[kept, 1], landmark),
            "model_range_correlation": sensor.range_correlation,
            "model_bearing_correlation": sensor.bearing_correlation,
            "chi2_per_dof": solution.chi2_per_dof}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=str(DATA), help="MRCLAM data set 2 folder")
    parser.add_argument("--robots", type=positive_int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args(argv)
    if not Path(args.data).is_dir():
        print(f"mrclam_residual_correlation: {args.data}: no such folder", file=sys.stderr)
        return 2
    logs = {r: read_mrclam(args.data, r) for r in (1, 2, 3, 4, 5)}
    print("robot  model        range lag-1 (model's ρ)   bearing lag-1 (model's ρ)   χ²/dof")
    for robot in args.robots:
        others = [log for r, log in logs.items() if r != robot]
        for label, noise in (("in sample", estimate_noise([logs[robot]], **DATASET_CALIBRATIONS).model),
                             ("other four", estimate_noise(others, **DATASET_CALIBRATIONS).model)):
            row = residual_row(logs[robot], noise)
            print(f"{robot:5d}  {label:11s}  {row['range_lag1']:5.2f} ({row['model_range_correlation']:.2f})"
                  f"              {row['bearing_lag1']:5.2f} ({row['model_bearing_correlation']:.2f})"
                  f"                {row['chi2_per_dof']:5.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
