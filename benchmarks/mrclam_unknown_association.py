"""MRCLAM in unknown association: every association the filter makes, judged against the barcodes.

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_unknown_association [--robots 1,2,3,4,5] [--seed 0] [--set FIELD=VALUE ...]
        [--json]

Per robot (each robot's noise fitted on its own log, as ``eval_mrclam --noise own``; the barcodes only score):
ATE, duplicate fraction, landmarks, rigid landmark error, the landmarks' NEES within the χ² 95 % bound and the
pose NEES median; the most probable particle's matches and how many went
to a landmark standing for *another* barcode (a landmark stands for the barcode most of the sightings that made or
matched it so far were of, as ``eval_mrclam`` attributes them); the filter's merges and the wrong ones (two
barcodes joined, as ``eval_mrclam_merges``); and with ``--set unknown_relative_drift='"consistent"'`` the
(particle, reading) pairs re-associated by ``estimation/fastslam/unknown_rescue.py``, right and wrong
(docs/fastslam-history.md, "Session 7: unknown association"). In the JSON, ``duplicate_pairs``: each pair of the final
map's landmarks that stand for one barcode, with what each merge rule sees of it (:func:`_duplicate_pairs`). A wrong
association is the confidently wrong output: it is counted for every variant.
"""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import estimation.dataset_slam as dataset_slam  # noqa: E402
import estimation.fastslam.filter as fastslam_filter  # noqa: E402
from benchmarks.eval_mrclam_merges import PLAIN, RunSetup, robots_main  # noqa: E402
from estimation.fastslam import FastSLAM, drift_merge, merging  # noqa: E402
from estimation.fastslam.linalg import sym_matrices  # noqa: E402
from estimation.landmark_scores import attribute_landmarks, count_sightings  # noqa: E402


class _Tally:
    """Sightings' votes so far and the counts of one run."""

    def __init__(self) -> None:
        self.votes: dict[int, dict[int, int]] = {}
        self.frame_ids = np.zeros(0, np.int64)
        self.counts = dict(matches=0, matches_other_barcode=0, rescued=0, rescued_same_barcode=0,
                           rescued_other_barcode=0, rescue_frames=0)

    def barcode(self, lid: int) -> int:
        return int(attribute_landmarks(self.votes, np.array([lid]))[0])


def run_robot(log, seed: int, overrides: dict, setup: RunSetup = PLAIN) -> dict:
    tally = _Tally()
    times, first = np.unique(log.sighting_times, return_index=True)
    bounds = np.append(first, len(log))[1:]
    ids_at = {float(t): log.landmark_ids[a:b] for t, a, b in zip(times, first, bounds, strict=True)}
    rescue = fastslam_filter.unknown_rescue.rescue

    def counted_rescue(tracker, rejected, cand_m, cand_lids, *args, **kwargs):
        out = rescue(tracker, rejected, cand_m, cand_lids, *args, **kwargs)
        if out is not None:
            tally.counts["rescue_frames"] += 1
            for row, j in zip(out.rows.tolist(), out.j.tolist(), strict=True):
                barcode = tally.barcode(int(cand_lids[row]))
                tally.counts["rescued"] += 1
                tally.counts["rescued_same_barcode"] += int(barcode == tally.frame_ids[j])
                tally.counts["rescued_other_barcode"] += int(barcode not in (-1, tally.frame_ids[j]))
        return out

    class Counting(FastSLAM):
        last: Counting | None = None

        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            Counting.last = self

        def update(self, observations):
            tally.frame_ids = ids_at[float(observations.timestamp)]
            report = super().update(observations)
            for j, lid in enumerate(report.best_matches.tolist()):
                if lid >= 0:
                    tally.counts["matches"] += 1
                    tally.counts["matches_other_barcode"] += int(tally.barcode(lid) not in (-1, tally.frame_ids[j]))
            count_sightings(tally.votes, tally.frame_ids, report)
            return report

    original = dataset_slam.FastSLAM
    dataset_slam.FastSLAM, fastslam_filter.unknown_rescue.rescue = Counting, counted_rescue
    try:
        run = dataset_slam.run_landmark_log(log, setup.config(overrides), np.random.default_rng(seed),
                                            noise=setup.noise(log), association="unknown", robot=log.name)
    finally:
        dataset_slam.FastSLAM, fastslam_filter.unknown_rescue.rescue = original, rescue
    pairs = [(a, b) for a, b, _ in Counting.last.merged_pairs]
    merged_ids = np.array([i for pair in pairs for i in pair], np.int64)
    barcode = dict(zip(merged_ids.tolist(), attribute_landmarks(tally.votes, merged_ids).tolist(), strict=True))
    m = run.metrics
    return {"robot": log.name, "ate_m": m["ate_m"], "duplicate_fraction": m["duplicate_fraction"],
            "landmarks": m["landmarks"], "true_landmarks": m["true_landmarks"],
            "landmark_error_rigid_median_m": m["landmark_error_rigid_median_m"],
            "landmark_nees_within_bound": m["landmark_nees_within_bound"], "pose_nees_median": m["pose_nees_median"],
            "merges": len(pairs),
            "merges_wrong": sum(barcode[a] != barcode[b] for a, b in pairs), **tally.counts,
            "duplicate_pairs": _duplicate_pairs(Counting.last, tally.votes)}


def _duplicate_pairs(slam: FastSLAM, votes: dict) -> list[dict]:
    """Every pair of the most probable particle's final landmarks that stand for one barcode (a duplicate), with
    what the merge rules see of it: the distance, d² under Σ_a + Σ_b (the plain merge), under Σ_a + Σ_b + C_a + C_b
    (co-visibility's gate: the drifts at creation), under Σ_a + Σ_b + H(w_b)(D_b − Φ D_a Φᵀ)⁺H(w_b)ᵀ (the drift
    between the creations, drift_merge.py), whether the two were detected in one frame, and co-visibility's evidence
    for "one point" so far (merged at ``merge_log_odds``)."""
    landmarks = slam.particle_map(slam.best_index, covariance="particle")
    ids = np.asarray(landmarks.ids, np.int64)
    barcode = attribute_landmarks(votes, ids)
    out = []
    for i, j in zip(*np.triu_indices(len(ids), 1), strict=True):
        if barcode[i] < 0 or barcode[i] != barcode[j]:
            continue
        (ia, a), (ib, b) = sorted([(i, int(ids[i])), (j, int(ids[j]))], key=lambda x: x[1])
        diff = landmarks.positions[ia] - landmarks.positions[ib]
        plain = landmarks.covariances[ia] + landmarks.covariances[ib]
        created = slam.drift.landmark_covariances(np.array([a, b])).sum(axis=0)
        since = sym_matrices(drift_merge.relative_drift(slam.drift, np.array([a]), np.array([b]),
                                                        landmarks.positions[ib][None]))[0]
        key = (a << merging.PAIR_SHIFT) | b
        out.append({"barcode": int(barcode[i]), "distance_m": float(np.linalg.norm(diff)),
                    **{f"d2_{name}": float(diff @ np.linalg.pinv(cov) @ diff)
                       for name, cov in (("plain", plain), ("creation_drift", plain + created),
                                         ("relative_drift", plain + since))},
                    "codetected": key in slam._codetected, "evidence": float(slam._pair_evidence.get(key, 0.0))})
    return out


def _print_rows(rows: list[dict]) -> None:
    print("| robot | ATE m | landmarks | duplicates | rigid lm err m | best matches (other barcode) | "
          "merges (wrong) | re-associated (same / other barcode) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['robot']} | {r['ate_m']:.3f} | {r['landmarks']}/{r['true_landmarks']} | "
              f"{100 * r['duplicate_fraction']:.1f} % | {r['landmark_error_rigid_median_m']:.3f} | "
              f"{r['matches']} ({r['matches_other_barcode']}) | {r['merges']} ({r['merges_wrong']}) | "
              f"{r['rescued']} ({r['rescued_same_barcode']} / {r['rescued_other_barcode']}) |")


def main(argv: list[str] | None = None) -> int:
    return robots_main(argv, "mrclam_unknown_association", __doc__.split("\n\n")[0], run_robot, _print_rows)


if __name__ == "__main__":
    sys.exit(main())
