"""MRCLAM unknown association: every new landmark the most probable particle makes, classified against the barcodes.

Per frame, per particle and observation, the plain gate as the filter computes it (d² under S = Σ + RQRᵀ + H P Hᵀ),
and the gate widened by the landmark's relative drift H (D_r − D_l)⁺ Hᵀ (drift.py). A creation (no landmark of the
particle passes the plain gate) is a *duplicate creation* if the particle already holds a landmark attributed
(majority vote of the best particle's sightings so far) to the observation's barcode.

Run from the repository root (a diagnosis: the filter's own gate before each update, ``FastSLAM.candidate_gate``;
~2 min CPU per robot):

    .venv/bin/python -m benchmarks.mrclam_unknown_creations ROBOT [SEED] ['{"FIELD": VALUE}'] [--range-calibration]

Prints the creations, how many were duplicate creations, how many of those had the right old landmark inside
the drift-widened gate, and whether it was the nearest or the only candidate there; the genuinely new ones that
some landmark passes under the widened gate (what a widened gate alone would mis-associate); frames with two or
more such re-sightings (what ``unknown_relative_drift="consistent"`` needs); the best particle's matches to a
landmark of another barcode. docs/fastslam-history.md, "Session 7: unknown association". ``--range-calibration``: each
robot's noise model also fits the camera's depth-not-range calibration (as ``eval_mrclam``'s option).
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import estimation.dataset_slam as ds
from benchmarks.eval_mrclam import DATA
from estimation.datasets import read_mrclam
from estimation.fastslam import FastSLAM, range_bearing_config
from estimation.fastslam.id_gate import psd_part
from estimation.fastslam.linalg import pose_uncertainty, sym_adjugate, sym_components, sym_matrices, sym_quadratic
from estimation.landmark_scores import count_sightings
from estimation.noise_estimation import estimate_noise
from runtime.commands.options import non_negative_int, positive_int


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("robot", type=positive_int, help="MRCLAM robot number (1-5)")
    parser.add_argument("seed", type=non_negative_int, nargs="?", default=0)
    parser.add_argument("overrides", nargs="?", default="{}", metavar="JSON",
                        help='range_bearing_config fields, e.g. \'{"FIELD": VALUE}\'')
    parser.add_argument("--range-calibration", action="store_true",
                        help="the noise model also fits the camera's depth-not-range calibration")
    args = parser.parse_args(argv)
    robot, seed, calibrate = args.robot, args.seed, args.range_calibration
    try:
        over = json.loads(args.overrides)
    except json.JSONDecodeError as error:
        parser.error(f"JSON overrides: {error}")
    if not DATA.is_dir():
        print(f"mrclam_unknown_creations: no data set at {DATA}", file=sys.stderr)
        return 2
    log = read_mrclam(DATA, robot)
    times, first = np.unique(log.sighting_times, return_index=True)
    bounds = np.append(first, len(log))[1:]
    frame_ids = {float(t): log.landmark_ids[a:b] for t, a, b in zip(times, first, bounds, strict=True)}
    votes: dict = {}
    rows = []      # per (best particle, observation) creation
    frames = []    # per frame: n obs, spawned-in-best, rescuable-in-best (correct old within widened gate)
    wrong_matches = [0, 0]


    def barcode_of(lid):
        t = votes.get(int(lid))
        return max(t.items(), key=lambda kv: (kv[1], -kv[0]))[0] if t else -1


    class Diag(FastSLAM):
        def update(self, obs):
            ids = frame_ids[float(obs.timestamp)]
            cfg = self.config
            best = int(np.argmax(self.log_weights))
            n_obs = len(ids)
            if int(self.store.n_blocks.max(initial=0)) and n_obs:
                gate_pairs = self.candidate_gate(obs)
                m, j, lid, d2 = gate_pairs.m, gate_pairs.j, gate_pairs.lid, gate_pairs.d2
                nu, s, lever = gate_pairs.innovation, gate_pairs.covariance, gate_pairs.lever
                poses, mj = self.poses, m * n_obs + j
                rel = psd_part(self.drift.robot[None] - sym_matrices(self.drift.landmark_pose_covariances(lid)))
                s2 = s + pose_uncertainty(sym_components(rel), lever)
                adj, det = sym_adjugate(s2)
                d2w = sym_quadratic(adj, nu) / det
                gate = cfg.mahalanobis_gate
                passed = np.zeros(len(poses) * n_obs, bool)
                passed[mj[d2 < gate]] = True
                spawn_all = ~passed.reshape(len(poses), n_obs).any(axis=0)      # (N,) no particle passes
                bc = np.array([barcode_of(x) for x in lid])
                sel_b = m == best
                n_resc = 0
                for jj in range(n_obs):
                    if passed[best * n_obs + jj]:
                        continue
                    k = np.flatnonzero(sel_b & (j == jj))
                    if len(k) == 0:
                        rows.append((obs.timestamp, jj, ids[jj], 0, np.nan, np.nan, 0, 0, -1, spawn_all[jj], np.nan))
                        continue
                    same = k[bc[k] == ids[jj]]
                    wide_ok = k[d2w[k] < gate]
                    if len(same):
                        i = same[np.argmin(d2[same])]
                        held, d2c, d2wc = 1, d2[i], d2w[i]
                        ang = np.sqrt(max(rel[i][2, 2], 0.0))
                    else:
                        held, d2c, d2wc, ang = 0, np.nan, np.nan, np.nan
                    nearest_w = k[np.argmin(d2w[k])]
                    correct_nearest = int(bc[nearest_w] == ids[jj]) if d2w[nearest_w] < gate else -1
                    if held and d2wc < gate:
                        n_resc += 1
                    rows.append((obs.timestamp, jj, ids[jj], held, d2c, d2wc, len(wide_ok),
                                 int(np.sum(bc[wide_ok] != ids[jj])), correct_nearest, spawn_all[jj], ang))
                frames.append((obs.timestamp, n_obs, n_resc))
            report = super().update(obs)
            for jj in range(n_obs):
                lidm = report.best_matches[jj]
                if lidm >= 0:
                    wrong_matches[0] += 1
                    wrong_matches[1] += int(barcode_of(lidm) not in (-1, ids[jj]))
            count_sightings(votes, ids, report)
            return report


    ds.FastSLAM = Diag
    noise = estimate_noise([log], range_calibration=calibrate).model
    run = ds.run_landmark_log(log, range_bearing_config(n_particles=100, **over), np.random.default_rng(seed),
                              noise=noise, association="unknown")
    r = np.array(rows, float)
    met = run.metrics
    print(f"robot{robot} seed{seed}: ATE {met['ate_m']:.3f} dup {met['duplicate_fraction']:.2f} "
          f"lm {met['landmarks']}  best-particle matches {wrong_matches[0]}, to another barcode {wrong_matches[1]}")
    held = r[:, 3] == 1
    wide = r[:, 5] < 11.345
    print(f"  creations in the best particle: {len(r)}; barcode already held (duplicate creation): {held.sum()} "
          f"(also every particle: {np.sum(held & (r[:, 9] == 1))})")
    print(f"  of the duplicate creations: correct old landmark within the widened gate {np.sum(held & wide)}; "
          f"widened nearest is correct {np.sum(held & (r[:, 8] == 1))}; "
          f"widened nearest wrong {np.sum(held & (r[:, 8] == 0))}; "
          f"unique widened candidate {np.sum(held & wide & (r[:, 6] == 1))}")
    print(f"  genuine new (barcode not held): {np.sum(~held)}; "
          f"some landmark passes widened: {np.sum(~held & (r[:, 6] > 0))}")
    if held.any():
        print(f"  plain d2 of the correct old one: median {np.nanmedian(r[held, 4]):.1f}  "
              f"q10/q90 {np.nanpercentile(r[held, 4], 10):.1f}/{np.nanpercentile(r[held, 4], 90):.1f};  widened median "
              f"{np.nanmedian(r[held, 5]):.1f}; relative-drift heading sd median {np.nanmedian(r[held, 10]):.3f} rad")
    f = np.array(frames, float)
    print(f"  frames {len(f)}; with >= 1 rescuable {np.sum(f[:, 2] >= 1)}; with >= 2 {np.sum(f[:, 2] >= 2)}; "
          f"obs/frame mean {f[:, 1].mean():.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
