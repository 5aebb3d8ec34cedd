"""Landmarks of a smoothed log that are one point: the correspondence test of GraphSLAM, after the filter.

Without identities (``association="unknown"``) a filter that drifted makes a landmark again when it comes back to
it: the map holds two landmarks for one point, and the trajectory between the two sightings is never corrected,
because nothing says they are one. Once the whole log is smoothed (:mod:`estimation.landmark_smoother`), the
question has an answer from the joint posterior (Thrun & Montemerlo 2006, GraphSLAM's correspondence test;
Probabilistic Robotics, table 11.8): the difference Δ = m_a − m_b of two landmarks has the covariance
C = Σ_aa + Σ_bb − Σ_ab − Σ_ba, and "a and b are one point" is Δ = 0. The test here:

- a pair is a *candidate* when d² = Δᵀ C⁻¹ Δ is within χ²₂ 99 % and no frame sighted both (two landmarks sighted in
  one frame are two points: mutual exclusion, as in the filter);
- a candidate is *merged* only when it is unambiguous: each of the two is the other's most likely candidate, and any
  other candidate of either is at least ``AMBIGUITY_RATIO`` times less likely (Gaussian likelihoods, normalisation
  included). Repeated structure (posts spaced within the drift) then leaves two landmarks apart: a duplicate left
  in the map costs a score, a wrong merge bends the whole trajectory, so the test prefers the first;
- merged pairs are joined (their sightings name one landmark), the log is smoothed again from the previous solution,
  and the test repeats with the tighter covariances that the loop closures give, until nothing more is merged.

After each round the merges are checked: a merge adds the two constraints Δ = 0, so the solution's χ² should rise
by about 2 per merge; a round whose rise is beyond χ² 99.9 % for its degrees of freedom is undone and its merges are
tried one at a time, the most likely first, each kept only if its own rise passes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.spatial
import scipy.stats

from .landmark_smoother import LandmarkLogProblem, Smoothed, smooth

CORRESPONDENCE_GATE = 9.21      # χ²₂ 99 %: a pair further apart than this is not a candidate
AMBIGUITY_RATIO = 100.0         # the next candidate must be this many times less likely than the one merged
MAX_ROUNDS = 30
_CHECK_QUANTILE = 0.999         # the χ² rise a round of merges may cause, for 2 dof per merge


@dataclass
class Correspondence:
    """The smoothed solution after merging, the problem it solved (landmark indices renumbered), ``merged_into``
    (L₀,): the final landmark of each original one, and ``merges``: (a, b, d²) in original indices, in the order
    they were made; ``rejected``: merges undone by the χ² check."""

    solution: Smoothed
    problem: LandmarkLogProblem
    merged_into: np.ndarray
    merges: list[tuple[int, int, float]]
    rejected: list[tuple[int, int, float]]
    rounds: int


def pair_statistics(solution: Smoothed, problem: LandmarkLogProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                                np.ndarray]:
    """Every pair (a < b) of sighted landmarks that no frame sighted both: (a, b, d², log-likelihood of Δ = 0)."""
    seen = np.flatnonzero(np.all(np.isfinite(solution.landmark_covariances.reshape(-1, 4)), axis=1))
    # exact pre-filter: d² ≤ gate needs |Δ| ≤ √gate · (√λ_a + √λ_b), λ the marginals' largest eigenvalues
    reach = np.sqrt(CORRESPONDENCE_GATE) * np.sqrt(np.linalg.eigvalsh(solution.landmark_covariances[seen])[:, -1])
    tree = scipy.spatial.cKDTree(solution.landmarks[seen])
    near = tree.query_pairs(2.0 * float(reach.max(initial=0.0)), output_type="ndarray")
    a, b = seen[near[:, 0]], seen[near[:, 1]]
    close = np.linalg.norm(solution.landmarks[a] - solution.landmarks[b], axis=1) <= (
        reach[near[:, 0]] + reach[near[:, 1]])
    a, b = np.minimum(a, b)[close], np.maximum(a, b)[close]
    covisible = _covisible(problem, solution.inliers, len(solution.landmarks))
    keep = ~covisible[a, b]
    a, b = a[keep], b[keep]
    joint = solution.landmark_joint_covariance
    ia, ib = 2 * a[:, None] + np.arange(2), 2 * b[:, None] + np.arange(2)
    block = lambda r, c: joint[r[:, :, None], c[:, None, :]]     # noqa: E731  (P, 2, 2) blocks
    cov = block(ia, ia) + block(ib, ib) - block(ia, ib) - block(ib, ia)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    delta = solution.landmarks[a] - solution.landmarks[b]
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    ok = det > 0
    d2 = np.full(len(a), np.inf)
    d2[ok] = (delta[ok, 0] ** 2 * cov[ok, 1, 1] - 2 * delta[ok, 0] * delta[ok, 1] * cov[ok, 0, 1]
              + delta[ok, 1] ** 2 * cov[ok, 0, 0]) / det[ok]
    log_likelihood = np.full(len(a), -np.inf)
    log_likelihood[ok] = -0.5 * (d2[ok] + np.log(det[ok]) + 2 * np.log(2 * np.pi))
    return a, b, d2, log_likelihood


def unambiguous_pairs(a, b, d2, log_likelihood) -> list[tuple[int, int, float]]:
    """The candidate pairs (within the gate) that are each other's most likely and clear of every other candidate of
    either by ``AMBIGUITY_RATIO``; most likely first. Pairs share no landmark."""
    gated = d2 < CORRESPONDENCE_GATE
    a, b, d2, ll = a[gated], b[gated], d2[gated], log_likelihood[gated]
    margin = np.log(AMBIGUITY_RATIO)
    chosen, used = [], set()
    for k in np.argsort(-ll):
        i, j = int(a[k]), int(b[k])
        if i in used or j in used:
            continue
        others = ((a == i) | (b == i) | (a == j) | (b == j))
        others[k] = False
        if np.any(ll[others] > ll[k] - margin):
            continue
        chosen.append((i, j, float(d2[k])))
        used.update((i, j))
    return chosen


def smooth_with_correspondences(problem: LandmarkLogProblem, initial_poses: np.ndarray,
                                initial_landmarks: np.ndarray, **smooth_options) -> Correspondence:
    """Smooth ``problem``, then merge landmarks the correspondence test finds to be one, round by round (module
    docstring). ``smooth_options`` go to :func:`~estimation.landmark_smoother.smooth`."""
    n_original = max(problem.n_landmarks, len(initial_landmarks))
    merged_into = np.arange(n_original)
    current = problem
    solution = smooth(current, initial_poses, initial_landmarks, **smooth_options)
    merges, rejected = [], []
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):  # noqa: B007  (the count is reported)
        pairs = unambiguous_pairs(*pair_statistics(solution, current))
        if not pairs:
            break
        attempt = _merged(current, solution, pairs, merged_into, **smooth_options)
        if _rise_passes(solution, attempt[1], len(pairs)):
            merges += [_in_original(merged_into, p) for p in pairs]
            current, solution, merged_into = attempt
            continue
        kept_any = False
        for original in [_in_original(merged_into, p) for p in pairs]:   # one at a time, the most likely first
            pair = (int(merged_into[original[0]]), int(merged_into[original[1]]), original[2])   # renumbered
            trial = _merged(current, solution, [pair], merged_into, **smooth_options)
            if _rise_passes(solution, trial[1], 1):
                merges.append(original)
                current, solution, merged_into = trial
                kept_any = True
            else:
                rejected.append(original)
        if not kept_any:
            break
    return Correspondence(solution, current, merged_into, merges, rejected, rounds)


def _in_original(merged_into: np.ndarray, pair: tuple[int, int, float]) -> tuple[int, int, float]:
    """A pair of current landmark indices as the first original landmark each stands for."""
    return int(np.flatnonzero(merged_into == pair[0])[0]), int(np.flatnonzero(merged_into == pair[1])[0]), pair[2]


def _rise_passes(before: Smoothed, after: Smoothed, n_merges: int) -> bool:
    """The χ² rise of ``n_merges`` merges within χ²(2 n_merges) at ``_CHECK_QUANTILE`` (outliers counted at the gate
    of the smoother: a sighting dropped by the merge is charged as if it had stayed at the bound)."""
    rise = _chi2_with_dropped(after) - _chi2_with_dropped(before)
    return rise <= scipy.stats.chi2.ppf(_CHECK_QUANTILE, 2 * n_merges)


def _chi2_with_dropped(solution: Smoothed) -> float:
    from .landmark_smoother import OUTLIER_CHI2
    return solution.chi2 + OUTLIER_CHI2 * float(np.count_nonzero(~solution.inliers))


def _merged(problem: LandmarkLogProblem, solution: Smoothed, pairs, merged_into, **smooth_options):
    """The problem with each pair's two landmarks one (renumbered 0..L'−1), smoothed from ``solution``."""
    n = len(solution.landmarks)
    target = np.arange(n)
    landmarks = solution.landmarks.copy()
    for i, j in ((p[0], p[1]) for p in pairs):
        keep, gone = min(i, j), max(i, j)
        target[gone] = keep
        landmarks[keep] = _information_mean(solution, keep, gone)
    kept, renumber = np.unique(target, return_inverse=True)
    index = renumber[problem.landmark_index]
    merged_problem = LandmarkLogProblem(problem.increments, problem.increment_variances, problem.pose_index, index,
                                        problem.ranges, problem.bearings, problem.range_sigmas,
                                        problem.bearing_sigmas)
    after = smooth(merged_problem, solution.poses, landmarks[kept], **smooth_options)
    return merged_problem, after, renumber[merged_into]


def _information_mean(solution: Smoothed, a: int, b: int) -> np.ndarray:
    """The two estimates combined by their marginal information (the smoother moves it from there)."""
    info_a, info_b = (np.linalg.inv(solution.landmark_covariances[k]) for k in (a, b))
    return np.linalg.solve(info_a + info_b, info_a @ solution.landmarks[a] + info_b @ solution.landmarks[b])


def _covisible(problem: LandmarkLogProblem, inliers: np.ndarray, n_landmarks: int) -> np.ndarray:
    """(L, L) bool: landmarks sighted (by kept sightings) at one pose."""
    incidence = sp.csr_matrix((np.ones(int(inliers.sum())), (problem.pose_index[inliers],
                                                              problem.landmark_index[inliers])),
                              shape=(problem.n_poses + 1, n_landmarks))
    incidence.data[:] = 1.0
    return (incidence.T @ incidence).toarray() > 0
