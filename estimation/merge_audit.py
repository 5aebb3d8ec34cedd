"""Each part of a merged name tested against the rest of it, right after the merge (issue 13, MRCLAM without
barcodes; session 31, helper C).

The unknown-association rounds (``benchmarks.mrclam_constellation``) merge a batch of names and keep it when the
smoother's truncated cost rises by no more than χ² 99 % for 2 per absorbed name. One wrong pairing among a hundred
right ones hides in that sum (session 30: robot 2 seed 2's round 2, a rise of 244.2 against 249.4 with one wrong
pairing). Here the merged map is asked, for each **part** of a merged name — its kept sightings that carried one
name before the merge — how much the fit would gain if the part were a landmark of its own: map_honesty's split
score (the first-order cost drop, χ²₂ under the smoother's model), with what it rests on: the part's offset from
the rest of the name, δ̂, and δ̂'s covariance given everything else the map holds.

The covariance says what the score can see. A part seen from a stretch held by nothing but odometry can slide with
the stretch: its δ̂ has a long axis, and a wrong part there (another post 0.7 m away) costs the fit almost nothing
(session 31: robot 5 seed 0's round-5 wrong part, 18 sightings of post 20 merged into post 19's name: δ̂ 0.51 m,
σ 0.016 × 0.49 m, score 10.2 — right parts of the same batch score 8.0 and 7.2 with δ̂ of 4–5 cm).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import chi2
from .landmark_smoother import LandmarkLogProblem, Smoothed
from .map_honesty import Run, sighting_times, split_scores

__all__ = ["PartSplits", "covisible_spacing", "floored_scores", "held_parts", "indistinguishable", "merged_parts",
           "part_splits"]


@dataclass(frozen=True)
class PartSplits:
    """For P parts: ``score`` (P,) the split score (χ²₂; NaN where the rest of the landmark holds nothing against
    the part), ``offset`` (P, 2) δ̂, the part's point minus the rest of its landmark (m, map frame), ``covariance``
    (P, 2, 2) δ̂'s covariance given every other variable of the map (m²). score = δ̂ᵀ covariance⁻¹ δ̂."""

    score: np.ndarray
    offset: np.ndarray
    covariance: np.ndarray

    def widest_sigma(self) -> np.ndarray:
        """(P,) the σ of δ̂ along its least certain axis (m; NaN where there is no score)."""
        out = np.full(len(self.score), np.nan)
        ok = np.isfinite(self.score)
        out[ok] = np.sqrt(np.linalg.eigvalsh(self.covariance[ok])[:, -1])
        return out


def merged_parts(problem: LandmarkLogProblem, solution: Smoothed, before: np.ndarray) -> list[Run]:
    """The parts of each merged landmark: ``before`` (S,) each of the problem's sightings' name before the merge
    (−1: it had none); each landmark whose kept sightings carried two or more names before is cut into one
    :class:`~estimation.map_honesty.Run` per earlier name (its kept sightings of that name, in time order). Landmarks
    of one earlier name, and sightings without one, give no part."""
    before = np.asarray(before)
    if before.shape != (len(problem.ranges),):
        raise ValueError(f"one earlier name a sighting: {before.shape} for {len(problem.ranges)} sightings")
    times = sighting_times(problem)
    kept = np.flatnonzero(np.asarray(solution.inliers, bool) & (before >= 0))
    out = []
    for landmark in np.unique(problem.landmark_index[kept]):
        mine = kept[problem.landmark_index[kept] == landmark]
        earlier = np.unique(before[mine])
        if len(earlier) < 2:
            continue
        for name in earlier:
            part = mine[before[mine] == name]
            part = part[np.argsort(times[part], kind="stable")]
            out.append(Run(int(landmark), part, float(times[part[0]]), float(times[part[-1]])))
    return out


def part_splits(problem: LandmarkLogProblem, solution: Smoothed, runs: list[Run]) -> PartSplits:
    """Each run's split score (the statistic of :func:`estimation.map_honesty.split_scores`, the same numbers), with
    the offset δ̂ = V⁻¹g it rests on and δ̂'s covariance V⁻¹: g = J_δᵀ r the gradient of the run's normalised
    residuals r with respect to an offset of its landmark in its sightings only, V = J_δᵀJ_δ − (J_xᵀJ_δ)ᵀ H⁻¹
    (J_xᵀJ_δ) that offset's information given every other variable (H the smoother's normal matrix). A run that is
    all of its landmark's kept sightings, or that the rest holds nothing against, gets NaN."""
    details: dict = {}
    score = split_scores(problem, solution, runs, details)
    if not runs:
        return PartSplits(np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2, 2)))
    return PartSplits(score, details["offset"], details["covariance"])


def floored_scores(splits: PartSplits, floor_m: float) -> np.ndarray:
    """(P,) each part's score with an offset of σ ``floor_m`` per axis allowed between the part and the rest of its
    landmark that the sighting model does not carry: δ̂ᵀ(C + σ²I)⁻¹δ̂, still χ²₂ (map_honesty.split_scores' floor).
    One post's names differ by a few centimetres (session 26: 3.5 cm rms per name; session 27 gave each name an
    offset of prior σ 3 cm), so a part of many sightings a few centimetres off its name is no disagreement."""
    if not (np.isfinite(floor_m) and floor_m >= 0):
        raise ValueError(f"the offset floor must be finite and ≥ 0 m, not {floor_m}")
    out = np.full(len(splits.score), np.nan)
    ok = np.isfinite(splits.score)
    wide = splits.covariance[ok] + floor_m ** 2 * np.eye(2)
    out[ok] = np.einsum("pi,pi->p", splits.offset[ok], np.linalg.solve(wide, splits.offset[ok][:, :, None])[:, :, 0])
    return out


def covisible_spacing(problem: LandmarkLogProblem, solution: Smoothed) -> float:
    """The smallest distance (m) between two landmarks of the map with kept sightings in one frame: two points the
    map itself says are distinct (a camera reports a post once a frame), so the nearest that two posts are known to
    stand. inf when no two landmarks share a frame."""
    kept = np.asarray(solution.inliers, bool)
    frame, landmark = problem.pose_index[kept], problem.landmark_index[kept]
    order = np.lexsort((landmark, frame))
    frame, landmark = frame[order], landmark[order]
    best = np.inf
    starts = np.flatnonzero(np.r_[True, np.diff(frame) > 0])
    ends = np.r_[starts[1:], len(frame)]
    for a, b in zip(starts, ends, strict=True):
        marks = np.unique(landmark[a:b])
        if len(marks) < 2:
            continue
        points = solution.landmarks[marks]
        gaps = np.linalg.norm(points[:, None] - points[None], axis=2)
        best = min(best, float(gaps[np.triu_indices(len(marks), 1)].min()))
    return best


def indistinguishable(widest_sd, spacing_m: float, alpha: float):
    """Whether an offset of σ ``widest_sd`` (m) along its widest axis could be ``spacing_m`` (the nearest two posts are
    known to stand, :func:`covisible_spacing`) and still score within χ²₂ at 1 − α: the map cannot tell the post it
    belongs to from a neighbour's (merge_audit's power rule; the parts of :func:`held_parts`, the groups of
    :func:`estimation.batch_audit.untestable_groups`, the runs of :mod:`estimation.naming_reliability`)."""
    return widest_sd * np.sqrt(chi2.ppf(1 - alpha, 2)) > spacing_m


def held_parts(splits: PartSplits, *, floor_m: float, spacing_m: float, alpha: float = 0.01) -> dict[str, np.ndarray]:
    """Which parts of a batch's merged names to hold back (each (P,) bool):

    - ``refused``: the floored score (:func:`floored_scores`) beyond χ²₂ at 1 − α/K, K the batch's parts with a
      score (Bonferroni: an honest batch holds one back with probability ≤ α);
    - ``untestable``: the part's offset could be ``spacing_m`` (the nearest two posts are known to stand,
      :func:`covisible_spacing`) along its widest axis and score within χ²₂ at 1 − α: the map cannot tell the
      part's post from a neighbour's, so merging it claims what nothing checks.
    """
    if not 0 < alpha < 1 or not spacing_m > 0:
        raise ValueError(f"need 0 < α < 1 and a spacing > 0 m, not {alpha} and {spacing_m}")
    ok = np.isfinite(splits.score)
    refused = np.zeros(len(ok), bool)
    if ok.any():
        refused[ok] = floored_scores(splits, floor_m)[ok] > chi2.isf(alpha / int(ok.sum()), 2)
    untestable = ok & indistinguishable(splits.widest_sigma(), spacing_m, alpha)
    return {"refused": refused, "untestable": untestable}
