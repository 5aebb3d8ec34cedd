"""MRCLAM unknown association: every match of the most probable particle to another post, taken apart.

Per frame, before the update, the plain gate as the filter computes it (d² under S = Σ + RQRᵀ + H P Hᵀ at the
predicted pose) for every (particle, reading, landmark); a landmark stands for the barcode most of the sightings
that made or matched it so far were of (as ``eval_mrclam`` attributes them). For each reading the most probable
particle (the one the filter's step 8 picks) matched to a landmark of another barcode:

- (a) the wrong landmark's d², the right one's (the particle's nearest landmark of the reading's barcode; "not
  held" if it has none) and whether the right one was inside the gate too (both in: an ambiguity);
- (b) whether any other particle matched the right landmark in that frame, the best of them by weight (its
  log-weight below the best's) and what resampling did to them (copies after the frame);
- (c) the best particle's pose error (predicted, in the start frame, against Vicon), beside that of the best
  right-matching particle, and for comparison over the best particle's right matches.

Also, over all the best particle's matches: right / wrong by the number of landmarks inside the gate (one or
several), and by the association's posterior p(chosen | z) among the gated candidates (Gaussian likelihoods with
their normalisers).

Run from the repository root (a diagnosis; the gate is the filter's own, ``FastSLAM.candidate_gate``; ~2-3 min a robot):

    .venv/bin/python -m benchmarks.mrclam_wrong_matches [--robots 1,2,3,4,5] [--seed 0] [--set FIELD=VALUE ...]
        [--json]
"""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import estimation.dataset_slam as dataset_slam  # noqa: E402
from benchmarks.eval_mrclam_merges import PLAIN, RunSetup, robots_main  # noqa: E402
from estimation.fastslam import FastSLAM  # noqa: E402
from estimation.geometry import between, wrap_angle  # noqa: E402
from estimation.landmark_scores import attribute_landmarks, count_sightings  # noqa: E402


def _pose_error(pose: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    return float(np.hypot(*(pose[:2] - truth[:2]))), float(abs(wrap_angle(pose[2] - truth[2])))


def run_robot(log, seed: int, overrides: dict, setup: RunSetup = PLAIN) -> dict:
    times, first = np.unique(log.sighting_times, return_index=True)
    bounds = np.append(first, len(log))[1:]
    ids_at = {float(t): log.landmark_ids[a:b] for t, a, b in zip(times, first, bounds, strict=True)}
    true_start = log.true_pose([times[0]])[0]
    votes: dict[int, dict[int, int]] = {}
    wrong: list[dict] = []
    right_pose_err: list[tuple[float, float]] = []
    timeline: list[tuple] = []     # per best-particle match: t, right, pose error m, rad, gated, posterior
    by_gated = np.zeros((2, 3), np.int64)          # rows right/wrong; columns 1, 2, >= 3 landmarks in the gate
    posterior_edges = np.array([0.5, 0.9, 0.99, 0.999])
    by_posterior = np.zeros((2, len(posterior_edges) + 1), np.int64)

    class Diagnosed(FastSLAM):
        last: Diagnosed | None = None

        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            Diagnosed.last = self
            self._frame: dict | None = None

        def update(self, obs):
            ids = ids_at[float(obs.timestamp)]
            self._frame = self._gate_table(obs, ids) if len(ids) and int(self.store.n_blocks.max(initial=0)) else None
            report = super().update(obs)
            count_sightings(votes, ids, report)
            return report

        def _gate_table(self, obs, ids) -> dict | None:
            gate = self.candidate_gate(obs)
            if len(gate.m) == 0:
                return None
            uniq, inv = np.unique(gate.lid, return_inverse=True)
            barcode = attribute_landmarks(votes, uniq)[inv]
            return dict(m=gate.m, j=gate.j, lid=gate.lid, d2=gate.d2, logdet=gate.log_det, right=barcode == ids[gate.j],
                        ids=ids, poses=self.poses.copy(), prior=self.log_weights.copy())

        def _check_self(self, best, matched, missed, named, z, miss_weight):
            super()._check_self(best, matched, missed, named, z, miss_weight)
            if self._frame is not None:
                self._frame.update(best=best, mm=matched.m.copy(), mj=matched.j.copy(),
                                   mlid=self.store.flat_lid[matched.g].copy())

    def judge(slam: Diagnosed, parents: np.ndarray) -> None:
        f = slam._frame
        if f is None or "best" not in f:
            return
        gate = slam.config.mahalanobis_gate
        n_obs, best = len(f["ids"]), f["best"]
        m, j, lid, d2, right = f["m"], f["j"], f["lid"], f["d2"], f["right"]
        truth = between(true_start, log.true_pose([float(slam._time)])[0])
        # the filter's log-likelihood of each particle (robust form: −½ min(d², gate) per reading)
        key = {(a, b, c): i for i, (a, b, c) in enumerate(zip(m.tolist(), j.tolist(), lid.tolist(), strict=True))}
        mrow = np.array([key[(a, b, c)] for a, b, c in zip(f["mm"].tolist(), f["mj"].tolist(), f["mlid"].tolist(),
                                                             strict=True)], np.int64)
        log_lik = -0.5 * gate * n_obs - 0.5 * np.bincount(f["mm"], d2[mrow] - gate, minlength=len(f["prior"]))
        post = f["prior"] + log_lik
        post -= post.max()
        copies = np.bincount(parents, minlength=len(post))
        for row in np.flatnonzero(f["mm"] == best):
            jj, r = int(f["mj"][row]), mrow[row]
            mine = np.flatnonzero((m == best) & (j == jj))
            gated = mine[d2[mine] < gate]
            lik = np.exp(-0.5 * d2[gated] - 0.5 * f["logdet"][gated])
            p_chosen = float(np.exp(-0.5 * d2[r] - 0.5 * f["logdet"][r]) / lik.sum())
            ok = bool(right[r])
            by_gated[int(not ok), min(len(gated), 3) - 1] += 1
            by_posterior[int(not ok), int(np.searchsorted(posterior_edges, p_chosen))] += 1
            err = _pose_error(f["poses"][best], truth)
            if ok:
                right_pose_err.append(err)
                timeline.append((float(slam._time), 1, err[0], err[1], len(gated), p_chosen))
                continue
            timeline.append((float(slam._time), 0, err[0], err[1], len(gated), p_chosen))
            held = mine[right[mine]]
            d2_right = float(d2[held].min()) if len(held) else float("nan")
            # other particles that matched this reading to a landmark of the right barcode
            others = np.flatnonzero((f["mj"] == jj) & right[mrow])
            om = f["mm"][others]
            # where the best particle held no landmark of the post, the right association was a new landmark
            creators = len(f["prior"]) - len(np.unique(m[(j == jj) & (d2 < gate)]))
            entry = dict(t=float(slam._time), d2_wrong=float(d2[r]), d2_right=d2_right, held=bool(len(held)),
                         gated=len(gated), p_chosen=p_chosen, pose_err_m=err[0], pose_err_rad=err[1],
                         right_particles=len(om), right_copies=int(copies[om].sum()) if len(om) else 0,
                         best_copies=int(copies[best]), creators=creators)
            if len(om):
                top = int(om[np.argmax(post[om])])
                entry.update(right_log_weight=float(post[top]),
                             right_pose_err_m=_pose_error(f["poses"][top], truth)[0],
                             right_pose_err_rad=_pose_error(f["poses"][top], truth)[1])
            wrong.append(entry)

    class Judged(Diagnosed):
        def update(self, obs):
            report = super().update(obs)
            judge(self, self._history[-1][2])
            return report

    original = dataset_slam.FastSLAM
    dataset_slam.FastSLAM = Judged
    try:
        run = dataset_slam.run_landmark_log(log, setup.config(overrides), np.random.default_rng(seed),
                                            noise=setup.noise(log), association="unknown", robot=log.name)
    finally:
        dataset_slam.FastSLAM = original
    row = _summary(log.name, run.metrics, wrong, right_pose_err, by_gated, by_posterior, posterior_edges)
    row.update(first_wrong=wrong[:20], timeline=timeline)
    return row


def _summary(name, metrics, wrong, right_pose_err, by_gated, by_posterior, edges) -> dict:
    def med(key, rows):
        vals = np.array([w[key] for w in rows if key in w and np.isfinite(w[key])], float)
        return float(np.median(vals)) if len(vals) else float("nan")

    held = [w for w in wrong if w["held"]]
    in_gate = [w for w in held if w["d2_right"] < 11.345]
    with_right = [w for w in wrong if w["right_particles"]]
    rp = np.array(right_pose_err, float).reshape(-1, 2)
    return {
        "robot": name, "ate_m": metrics["ate_m"], "duplicate_fraction": metrics["duplicate_fraction"],
        "matches": int(by_gated.sum()), "wrong": len(wrong),
        "right_by_gated_1_2_3plus": by_gated[0].tolist(), "wrong_by_gated_1_2_3plus": by_gated[1].tolist(),
        "posterior_edges": edges.tolist(), "right_by_posterior": by_posterior[0].tolist(),
        "wrong_by_posterior": by_posterior[1].tolist(),
        "wrong_right_held": len(held), "wrong_right_in_gate": len(in_gate),
        "d2_wrong_median": med("d2_wrong", wrong), "d2_right_median": med("d2_right", held),
        "wrong_with_right_particle": len(with_right),
        "right_particle_log_weight_median": med("right_log_weight", with_right),
        "right_particles_resampled_away": sum(w["right_copies"] == 0 for w in with_right),
        "wrong_not_held_with_creator": sum(w["creators"] > 0 for w in wrong if not w["held"]),
        "wrong_pose_err_m_median": med("pose_err_m", wrong), "wrong_pose_err_rad_median": med("pose_err_rad", wrong),
        "right_particle_pose_err_m_median": med("right_pose_err_m", with_right),
        "right_particle_pose_err_rad_median": med("right_pose_err_rad", with_right),
        "right_match_pose_err_m_median": float(np.median(rp[:, 0])) if len(rp) else float("nan"),
        "right_match_pose_err_rad_median": float(np.median(rp[:, 1])) if len(rp) else float("nan"),
    }


def _print_rows(rows: list[dict]) -> None:
    for r in rows:
        print(f"{r['robot']}: ATE {r['ate_m']:.2f} m, duplicates {100 * r['duplicate_fraction']:.0f} %; best "
              f"particle's matches {r['matches']}, to another post {r['wrong']}")
        print(f"  by landmarks in the gate (1 / 2 / 3+): right {r['right_by_gated_1_2_3plus']}, wrong "
              f"{r['wrong_by_gated_1_2_3plus']}")
        print(f"  by posterior of the chosen one (<{r['posterior_edges']}): right {r['right_by_posterior']}, wrong "
              f"{r['wrong_by_posterior']}")
        print(f"  (a) right post held {r['wrong_right_held']}, inside the gate {r['wrong_right_in_gate']}; d² median "
              f"wrong {r['d2_wrong_median']:.1f}, right {r['d2_right_median']:.1f}")
        print(f"  (b) another particle matched right: {r['wrong_with_right_particle']}; its log-weight below the "
              f"best's median {r['right_particle_log_weight_median']:.1f}; all resampled away "
              f"{r['right_particles_resampled_away']}; right post not held and some particle made a new landmark "
              f"{r['wrong_not_held_with_creator']} of {r['wrong'] - r['wrong_right_held']}")
        print(f"  (c) pose error of the best when wrong: {r['wrong_pose_err_m_median']:.2f} m "
              f"{r['wrong_pose_err_rad_median']:.3f} rad; of the best right-matching particle "
              f"{r['right_particle_pose_err_m_median']:.2f} m {r['right_particle_pose_err_rad_median']:.3f} rad; of "
              f"the best on its right matches {r['right_match_pose_err_m_median']:.2f} m "
              f"{r['right_match_pose_err_rad_median']:.3f} rad")


def main(argv: list[str] | None = None) -> int:
    return robots_main(argv, "mrclam_wrong_matches", __doc__.split("\n\n")[0], run_robot, _print_rows)


if __name__ == "__main__":
    sys.exit(main())
