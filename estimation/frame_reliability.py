"""Reliability of a smoothed map's frame (Baarda 1968; Förstner 1987): which sightings nothing else checks, and how
far an error in one of them that no test could find would move the map's frame.

Why: the map's frame is pose 0, the robot at its first sighting, and the map is tied to it by whatever sightings
and odometry increments join the first poses to the landmarks. On MRCLAM robot 1 that is one bearing (7.00 s,
landmark 11) that nothing else checks: its residual is ~0 whatever its error, so no outlier test can find the
0.067 rad it is off, and the landmarks' covariance (the inverse information, :mod:`estimation.landmark_smoother`)
says the frame is known to 0.024 rad while it is 0.055 rad turned (session 41 (A)). The covariance cannot show
such an error; the design of the problem can: this module asks it, without the truth.

The quantities, for the smoother's whitened Jacobian J (rows: normalised residuals, so unit weights; the same
J whose JᵀJ = H gives every covariance of the solution: :func:`~estimation.landmark_smoother.solution_jacobian`):

- the redundancy matrix of a group of rows i (a sighting's range and bearing), R_ii = I − J_i H⁻¹ J_iᵀ: the share of
  an error in those rows that shows in their own residuals (v = R ε, the residuals' covariance R); its trace, the
  sighting's redundancy number r_i ∈ [0, 2], is 2 for a sighting the others fix completely and 0 for one nothing
  else checks. Over all rows Σ r = rows − unknowns (the χ²'s degrees of freedom).
- internal reliability: the minimal detectable bias of one component c (range or bearing) of sighting i,
  ∇₀ = δ₀ σ_c / √(R_ii)_cc: the error the w-test of that component (its residual over its own σ √(R_ii)_cc)
  finds with probability β at level α. δ₀ = z(1 − α/2) + z(β) = 3.29 + 0.84 = 4.13 for α = 0.1 % and β = 80 %,
  Baarda's data snooping values (:data:`DELTA_0`). The smoother's own cut (χ²₂ 99 % on the two *normalised*
  residuals, not the studentised ones) is weaker where r is small (its residual shrinks with R, the cut does
  not widen), so an error of ∇₀ passes it at least as often: ∇₀ is a lower bound of what the smoother misses.
- external reliability on the frame: the frame is the rigid motion g = (dx, dy, dθ) of the landmarks about pose 0
  (:func:`~estimation.landmark_scores.rigid_functional`, here at the estimated positions of every landmark sighted:
  no truth needed), a linear function of the unknowns. An error ∇ in component c of sighting i moves the solution
  by H⁻¹ J_iᵀ (∇/σ_c) e_c (linear), so the frame by δg = (J_i u)_c ∇/σ_c with u = H⁻¹ gᵀ: one solve with three
  right-hand sides for every sighting. The frame's own σ is √(g H⁻¹ gᵀ).

The redundancy blocks need the blocks of H⁻¹ at the columns each row touches (a pose's and a landmark's, or two
consecutive poses'): from :class:`~estimation.landmark_smoother.NormalFactor`'s one factorisation, the landmarks'
block S⁻¹ (S the Schur complement), the cross blocks −X S⁻¹ (X = H_pp⁻¹ H_pl) and the poses' band of H_pp⁻¹ by the
Takahashi recursion on its banded Cholesky factor (O(T); every entry within the band is exact), plus X S⁻¹ Xᵀ. So
the figures are exact for the linearised problem at the solution, every sighting's, at the cost of about one more
factorisation of H.

With sighting offsets (the unknown-association chain's last smoothings, :mod:`estimation.chain_map`; session 42
(A2)) the explicit offsets are dense columns beside the landmarks', so nothing changes but the frame's covariance,
which gains the sole groups' σ² I (:func:`~estimation.landmark_smoother.sole_offset_groups`, the smoother's own
rule). The chain names a sighting by its own name, and by its barcode only where the truth scores the map
(``label``, ``barcodes`` of :func:`reliability_metrics`).

What it is not: a test that an error is there. A small redundancy says the data cannot tell, a large external
effect says what that would cost the frame; robot 1's first bearing is both, and its actual error is inside what
this says could go unseen.

Measured on MRCLAM (session 42 (A)): robots 1 and 5 rest on their first glimpse (its bearing's (R)_cc 0.05-0.20 with
the leave-one-out models, 6-12 σ of heading), robot 4 on one range with those models (4.3 σ in x), robots 2 and 3
on none; the worst effect covered every robot's actual frame error. Why no covariance is inflated from it: an
allowance for outliers at the smoother's own cut rate adds ~1 % to robot 1's heading σ (a rare error that happened
is not a variance), and removing the flagged sighting's information (Sherman–Morrison) leaves robot 1 at ~50 % of
its landmarks within bound while it doubles robot 5's σ; nor is the sighting dropped: the frame is the pose of the
first sighting, so the next glimpse becomes the lone tie (robot 1: 7.50, 7.98, 8.22 s in turn).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .landmark_scores import rigid_functional
from .landmark_smoother import LandmarkLogProblem, NormalFactor, Smoothed, sole_offset_groups, solution_jacobian

DELTA_0 = 4.13        # Baarda's δ₀: the w-test at α = 0.1 % (two-sided, 3.29) finding a bias with β = 80 % (+0.84)
COMPONENTS = ("range", "bearing")
_NO_REDUNDANCY = 1e-12   # (R_ii)_cc below this: nothing checks the component (its ∇₀ is infinite)
_PAIRS_PER_CHUNK = 200_000


@dataclass(frozen=True)
class FrameReliability:
    """Per sighting s (S,) of the problem (a sighting cut as an outlier: NaN throughout; it was found):
    ``redundancy`` (S, 2, 2) its block R_ss of the redundancy matrix (range, bearing), ``minimal_bias`` (S, 2) each
    component's ∇₀ (m, rad; inf where nothing checks it), ``frame_effect`` (S, 2, 3) the frame's (dx, dy, dθ)
    (m, m, rad) moved by that ∇₀ in that component; the frame's own covariance ``frame_covariance`` (3, 3) and
    ``delta0``."""

    redundancy: np.ndarray
    minimal_bias: np.ndarray
    frame_effect: np.ndarray
    frame_covariance: np.ndarray
    delta0: float

    @property
    def frame_sd(self) -> np.ndarray:
        """(3,) the frame's σ of (dx, dy, dθ) (m, m, rad)."""
        return np.sqrt(np.diag(self.frame_covariance))

    @property
    def redundancy_numbers(self) -> np.ndarray:
        """(S,) each sighting's r = tr R_ss ∈ [0, 2] (NaN if cut)."""
        return np.trace(self.redundancy, axis1=1, axis2=2)

    def heading_effect(self) -> np.ndarray:
        """(S, 2) |dθ| (rad) of each component's ∇₀."""
        return np.abs(self.frame_effect[:, :, 2])

    def translation_effect(self) -> np.ndarray:
        """(S, 2) |(dx, dy)| (m) of each component's ∇₀."""
        return np.hypot(self.frame_effect[:, :, 0], self.frame_effect[:, :, 1])


def frame_reliability(problem: LandmarkLogProblem, solution: Smoothed, delta0: float = DELTA_0, *,
                      pose: int = 0) -> FrameReliability:
    """The reliability figures of every sighting of ``solution`` (see the module docstring), for the frame of pose
    ``pose`` (0, the default: the map's own, the first sighting's; another: the map seen from that pose,
    :func:`frame_functional`). Needs at least two
    landmarks with a kept sighting (a frame's rotation needs two points). With sighting offsets
    (:class:`~estimation.landmark_smoother.SightingOffset`, the unknown-association chain's last smoothings) a
    sighting's columns are its pose's, its landmark's and its group's offset (dense, after the landmarks'); a sole
    group's offset, marginalised by the smoother, enters the sightings only as a sum with its landmark, so it changes
    no redundancy nor effect, and adds its σ² I to its landmark in the frame's covariance, as
    :func:`~estimation.landmark_smoother.joint_landmark_covariance` has it."""
    frame = frame_problem(problem, solution, pose)
    redundancy = sighting_redundancy(problem, solution, frame.inverse)
    in_sigmas = bias_in_sigmas(redundancy, delta0)
    sigmas = np.column_stack([problem.range_sigmas, problem.bearing_sigmas])
    return FrameReliability(redundancy, in_sigmas * sigmas, frame_effects(problem, solution, frame, in_sigmas),
                            0.5 * (frame.covariance + frame.covariance.T), float(delta0))


def _sighting_rows(problem: LandmarkLogProblem, solution: Smoothed) -> tuple[np.ndarray, np.ndarray]:
    """The kept sightings (K,) and their two rows of the whitened Jacobian (K, 2)."""
    kept = np.flatnonzero(solution.inliers)
    rows = 3 * problem.n_poses + 2 * kept
    return kept, np.column_stack([rows, rows + 1])


def sighting_redundancy(problem: LandmarkLogProblem, solution: Smoothed, inverse: SelectedInverse) -> np.ndarray:
    """(S, 2, 2) each sighting's block R_ss = I − J_s H⁻¹ J_sᵀ (NaN for a sighting cut): the same for every frame
    (it is the data's, not the frame's)."""
    kept, groups = _sighting_rows(problem, solution)
    redundancy = np.full((len(problem.ranges), 2, 2), np.nan)
    redundancy[kept] = np.eye(2) - inverse.hat_blocks(groups)
    return redundancy


def bias_in_sigmas(redundancy: np.ndarray, delta0: float = DELTA_0) -> np.ndarray:
    """(S, 2) each component's ∇₀ in units of its own σ, δ₀ / √(R_ss)_cc (inf where nothing checks it, NaN if cut)."""
    own = np.diagonal(redundancy, axis1=1, axis2=2)                              # (S, 2) (R_ss)_cc
    with np.errstate(divide="ignore", invalid="ignore"):
        in_sigmas = np.where(own > _NO_REDUNDANCY, delta0 / np.sqrt(np.maximum(own, _NO_REDUNDANCY)), np.inf)
    return np.where(np.isnan(own), np.nan, in_sigmas)


def frame_effects(problem: LandmarkLogProblem, solution: Smoothed, frame: FrameProblem,
                  in_sigmas: np.ndarray) -> np.ndarray:
    """(S, 2, 3) the (dx, dy, dθ) of ``frame`` moved by each component's ∇₀ (``in_sigmas`` of its σ; NaN if cut)."""
    kept, groups = _sighting_rows(problem, solution)
    per_unit = np.full((len(problem.ranges), 2, 3), np.nan)                      # δg of a bias of one σ
    per_unit[kept] = (frame.inverse.jac[groups.ravel()] @ frame.gain).reshape(-1, 2, 3)
    with np.errstate(invalid="ignore"):
        return np.where(per_unit == 0, 0.0, per_unit * in_sigmas[:, :, None])


def _framed(problem: LandmarkLogProblem, solution: Smoothed) -> np.ndarray:
    """(L,) bool: the landmarks with a kept sighting, the points the frame's rigid motion is of."""
    seen = np.zeros(len(solution.landmarks), bool)
    seen[problem.landmark_index[np.asarray(solution.inliers, bool)]] = True
    return seen


def has_frame(problem: LandmarkLogProblem, solution: Smoothed) -> bool:
    """Whether ``solution`` has a frame to speak of: two landmarks with a kept sighting (a rotation needs two
    points)."""
    return int(np.count_nonzero(_framed(problem, solution))) >= 2


@dataclass(frozen=True)
class FrameProblem:
    """What every question about a smoothed map's frame asks of the problem's design, from one factorisation:
    ``inverse`` (:class:`SelectedInverse` over the ``free`` columns of the whitened Jacobian: the poses' band, the
    landmarks with a kept sighting ``seen``, the dense extras), ``width`` the columns of a pose, ``functional``
    (3, free) the frame (the seen landmarks' rigid motion about pose 0) on those columns, ``gain`` H⁻¹ gᵀ (free, 3)
    and the frame's ``covariance`` (3, 3), with the sole offset groups' σ² I (marginalised by the smoother)."""

    inverse: SelectedInverse
    free: np.ndarray
    seen: np.ndarray
    width: int
    functional: np.ndarray
    gain: np.ndarray
    covariance: np.ndarray


def frame_problem(problem: LandmarkLogProblem, solution: Smoothed, pose: int = 0) -> FrameProblem:
    """``solution``'s :class:`FrameProblem`, for the frame of pose ``pose`` (0: the map's own; see
    :func:`frame_functional`). Needs a frame (:func:`has_frame`; ValueError otherwise)."""
    t = problem.n_poses
    seen = _framed(problem, solution)
    if seen.sum() < 2:
        raise ValueError(f"a frame needs two landmarks with a kept sighting, not {int(seen.sum())}")
    jac, width = solution_jacobian(problem, solution)
    free = np.ones(jac.shape[1], bool)
    free[width * t:width * t + 2 * len(solution.landmarks)] = np.repeat(seen, 2)
    inverse = SelectedInverse(jac, free, t, width)
    return framed_at(problem, solution, FrameProblem(inverse, free, seen, width, np.zeros((3, 0)),
                                                     np.zeros((0, 3)), np.zeros((3, 3))), pose)


def framed_at(problem: LandmarkLogProblem, solution: Smoothed, frame: FrameProblem, pose: int) -> FrameProblem:
    """``frame`` (its factorisation kept) asked of the frame of pose ``pose``: its functional, gain and covariance
    (one solve with three right-hand sides)."""
    t, width, seen = problem.n_poses, frame.width, frame.seen
    functional = frame_functional(solution, seen, width, t, int(frame.free.sum()), pose)
    gain = frame.inverse.factor.solve(functional.T)                              # H⁻¹ gᵀ, (n, 3)
    covariance = functional @ gain
    if solution.sighting_offset is not None and solution.sighting_offset.on:
        sole = np.zeros(len(solution.landmarks), bool)
        sole[sole_offset_groups(problem)[:, 0]] = True
        on_sole = np.repeat(sole[seen], 2)                                       # the seen landmarks' columns
        rigid = functional[:, width * t:width * t + 2 * int(seen.sum())][:, on_sole]
        covariance = covariance + solution.sighting_offset.sigma_m ** 2 * rigid @ rigid.T
    return FrameProblem(frame.inverse, frame.free, seen, width, functional, gain, covariance)


QUARTER_TURN = np.array([[0.0, -1.0], [1.0, 0.0]])    # J: J v is v turned by +90°


def frame_functional(solution: Smoothed, seen: np.ndarray, width: int, t: int, n_free: int,
                     pose: int = 0) -> np.ndarray:
    """(3, n_free) the frame of pose ``pose`` as a linear function of the free unknowns (poses 1..T, ``width``
    columns each, then the ``seen`` landmarks' two): the least-squares rigid motion (dx, dy, dθ), about that pose
    and along its axes, of the seen landmarks as that pose sees them, m_j = R(θ_k)ᵀ (l_j − p_k). Pose 0 is the
    origin (fixed): the landmarks' rigid motion about it (:func:`~estimation.landmark_scores.rigid_functional`). For
    a pose k ≥ 1, δm_j = Rᵀ δl_j − Rᵀ δp_k − δθ_k J m_j: the landmarks' columns take G_j Rᵀ, the pose's
    −Σ_j G_j Rᵀ on (x, y) and −Σ_j G_j J m_j on θ (G_j the rigid functional's columns of landmark j at the m's)."""
    functional = np.zeros((3, n_free))
    landmarks = solution.landmarks[seen]
    columns = slice(width * t, width * t + 2 * len(landmarks))
    if pose == 0:
        functional[:, columns] = rigid_functional(landmarks)
        return functional
    if not 1 <= pose <= t:
        raise ValueError(f"pose {pose} is not one of the solution's 0..{t}")
    x, y, theta = solution.poses[pose]
    c, s = np.cos(theta), np.sin(theta)
    rotation = np.array([[c, -s], [s, c]])
    seen_from = (landmarks - [x, y]) @ rotation                                  # rows Rᵀ (l_j − p_k)
    per_landmark = rigid_functional(seen_from).reshape(3, -1, 2)                 # G_j (3, K, 2)
    functional[:, columns] = (per_landmark @ rotation.T).reshape(3, -1)         # G_j Rᵀ
    at = width * (pose - 1)
    functional[:, at:at + 2] = -per_landmark.sum(axis=1) @ rotation.T
    functional[:, at + 2] = -np.einsum("akc,kc->a", per_landmark, seen_from @ QUARTER_TURN.T)
    return functional


class SelectedInverse:
    """Blocks of H⁻¹ (H = JᵀJ over the ``free`` columns of ``jac``, its first width·T the poses' band, the rest
    dense) at the columns rows of J touch, from one :class:`NormalFactor`; ``hat_blocks`` gives J_G H⁻¹ J_Gᵀ per
    group of rows G. A row may touch the columns of one pose and any dense ones, or of two consecutive poses (every
    factor of the smoother does)."""

    def __init__(self, jac: sp.spmatrix, free: np.ndarray, t: int, width: int) -> None:
        self.jac = sp.csr_matrix(jac)[:, np.flatnonzero(free)]
        self.n_poses = width * t
        self.factor = NormalFactor((self.jac.T @ self.jac).tocsc(), t, width)
        self.half = 2 * width - 1
        self.pose_band = band_inverse(self.factor.band) if t else np.zeros((self.half + 1, 0))
        self.dense = self.factor.landmark_covariance()                   # S⁻¹
        self.cross = self.factor.x @ self.dense                          # X S⁻¹ (its negative is H⁻¹'s pose-dense)

    def entries(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """H⁻¹[a, b] for column index arrays a, b (same shape) among the free columns."""
        n = self.n_poses
        out = np.zeros(len(a))
        pp, pd, dp, dd = (a < n) & (b < n), (a < n) & (b >= n), (a >= n) & (b < n), (a >= n) & (b >= n)
        if pp.any():
            lo, hi = np.minimum(a[pp], b[pp]), np.maximum(a[pp], b[pp])
            if np.any(hi - lo > self.half):
                raise ValueError("a row touches poses further apart than the band")
            out[pp] = self.pose_band[hi - lo, lo] + np.einsum("ij,ij->i", self.factor.x[a[pp]], self.cross[b[pp]])
        out[pd] = -self.cross[a[pd], b[pd] - n]
        out[dp] = -self.cross[b[dp], a[dp] - n]
        out[dd] = self.dense[a[dd] - n, b[dd] - n]
        return out

    def quadratic_forms(self, rows: sp.spmatrix) -> np.ndarray:
        """(G,) a H⁻¹ aᵀ for each row a of ``rows`` (G, free columns), a row touching the columns of one pose and
        any dense ones, or of two consecutive poses (as a row of J may)."""
        rows = sp.csr_matrix(rows)
        group, a, b, weight = _row_pairs(rows, rows)
        total = np.zeros(rows.shape[0])
        for start in range(0, len(a), _PAIRS_PER_CHUNK):
            part = slice(start, start + _PAIRS_PER_CHUNK)
            total += np.bincount(group[part], weight[part] * self.entries(a[part], b[part]), minlength=rows.shape[0])
        return total

    def hat_blocks(self, groups: np.ndarray) -> np.ndarray:
        """(G, m, m) J_G H⁻¹ J_Gᵀ for row groups ``groups`` (G, m) (row indices of ``jac``)."""
        groups = np.asarray(groups, int)
        count, m = groups.shape
        out = np.zeros((count, m, m))
        for i in range(m):
            for j in range(i, m):
                group, a, b, weight = _row_pairs(self.jac[groups[:, i]], self.jac[groups[:, j]])
                total = np.zeros(count)
                for start in range(0, len(a), _PAIRS_PER_CHUNK):
                    part = slice(start, start + _PAIRS_PER_CHUNK)
                    total += np.bincount(group[part], weight[part] * self.entries(a[part], b[part]),
                                         minlength=count)
                out[:, i, j] = out[:, j, i] = total
        return out


def _row_pairs(first: sp.csr_matrix, second: sp.csr_matrix):
    """For rows g of two CSR matrices of equal height, every pair of a nonzero of first[g] and one of second[g]:
    (g, column a, column b, first[g, a] · second[g, b]) as flat arrays."""
    first.sort_indices()
    second.sort_indices()
    n1, n2 = np.diff(first.indptr), np.diff(second.indptr)
    per = n1 * n2
    group = np.repeat(np.arange(len(per)), per)
    q = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per)
    stride = n2[group]
    i1 = first.indptr[group] + q // np.maximum(stride, 1)
    i2 = second.indptr[group] + q % np.maximum(stride, 1)
    return group, first.indices[i1], second.indices[i2], first.data[i1] * second.data[i2]


def band_inverse(band: np.ndarray) -> np.ndarray:
    """The band of A⁻¹ from A's banded upper Cholesky factor U (A = UᵀU; ``band`` (p + 1, n) in
    scipy.linalg.cholesky_banded's upper form, U[i, i + d] = band[p − d, i + d]): Z (p + 1, n) with
    Z[d, i] = (A⁻¹)[i, i + d] (0 past the end). Takahashi's recursion from the last row up:
    Z[i, j] = (δ_ij / U_ii − Σ_{k = i+1}^{i+p} U_ik Z[k, j]) / U_ii, which reads only entries within the band."""
    p, n = band.shape[0] - 1, band.shape[1]
    out = np.zeros((p + 1, n))
    window = np.zeros((p, p))               # A⁻¹[i+1 : i+1+p, i+1 : i+1+p] (the part past the end stays 0)
    diagonal = band[p]
    for i in range(n - 1, -1, -1):
        m = min(p, n - 1 - i)
        u = band[p - np.arange(1, m + 1), i + np.arange(1, m + 1)]
        row = -(u @ window[:m, :m]) / diagonal[i]
        own = (1.0 / diagonal[i] - u @ row) / diagonal[i]
        out[0, i] = own
        out[1:m + 1, i] = row
        if p:
            shifted = np.zeros((p, p))
            shifted[0, 0] = own
            shifted[0, 1:m + 1] = shifted[1:m + 1, 0] = row[:p - 1] if m == p else row
            shifted[1:, 1:] = window[:p - 1, :p - 1]
            window = shifted
    return out


AXES = ("x", "y", "heading")


def reliability_metrics(problem: LandmarkLogProblem, solution: Smoothed, times: np.ndarray,
                        landmark_ids: np.ndarray, *, label: str = "landmark",
                        barcodes: np.ndarray | None = None, pose: int = 0) -> dict:
    """The figures a data set run reports (``times`` (T,) each pose's log time, pose k at times[k − 1];
    ``landmark_ids`` (L,) each landmark index's identity, given in the sightings' dicts under ``label``: "landmark"
    for the known-ID smoother's barcodes, "name" for the unknown-association chain's own names; ``barcodes`` (S,),
    if given, each sighting's barcode under "barcode": for a chain scored against a truth), all from the problem's
    design, none from a truth:

    - ``frame_reliability_sd`` [σx, σy, σθ]: the frame's own σ (m, m, rad);
    - ``frame_reliability_effect`` [|dx|, |dy|, |dθ|]: the most one component's ∇₀ of one sighting moves each of the
      frame's coordinates, ``frame_reliability_effect_sd`` the most in units of its σ (each axis's worst sighting);
    - ``frame_reliability_heading_sighting`` / ``_translation_sighting``: the sighting that moves the heading (the
      x or y) the most in σ: its time, landmark, component, redundancy number r, the component's own (R)_cc, ∇₀ and
      the frame's (dx, dy, dθ) it gives;
    - ``frame_reliability_unchecked``: whether some coordinate's worst effect passes δ₀ σ: an error the data's test
      finds with probability β₀ = 80 % at α₀ = 0.1 % no more often than that, moving the frame by as much as the same
      test on that coordinate would find if its truth were known (Baarda's B method: one δ₀ for both). Then the frame's
      covariance does not hold what one sighting can do to it unseen (:func:`reliability_warning` says it);
    - ``sighting_redundancy_min`` / ``_median``: over the kept sightings; ``frame_reliability_delta0``.

    ``pose``: the frame asked about, 0 the map's own (the first sighting's), another pose k the map as pose k sees it
    (:func:`frame_functional`; the frame :mod:`estimation.map_frame` may choose).

    {} when there is no frame to speak of (fewer than two landmarks with a kept sighting); any other error of the
    figures (a solution that is not finite, an information matrix that is not positive definite) propagates."""
    if not has_frame(problem, solution):
        return {}
    rel = frame_reliability(problem, solution, pose=pose)
    sd = rel.frame_sd
    effect = np.abs(rel.frame_effect)                                   # (S, 2, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(effect == 0, 0.0, effect / sd)
    kept = np.flatnonzero(solution.inliers)
    ratio_kept = ratio[kept].reshape(-1, 3)                             # (2K, 3): rows (sighting, component)
    worst = np.argmax(ratio_kept, axis=0)                               # per axis
    numbers = rel.redundancy_numbers[kept]

    def sighting(row: int) -> dict:
        s, c = int(kept[row // 2]), row % 2
        barcode = {} if barcodes is None else {"barcode": int(barcodes[s])}
        return {"time_s": float(times[problem.pose_index[s] - 1]),
                label: int(landmark_ids[problem.landmark_index[s]]), **barcode, "component": COMPONENTS[c],
                "redundancy": float(rel.redundancy_numbers[s]),
                "component_redundancy": float(rel.redundancy[s, c, c]), "minimal_bias": float(rel.minimal_bias[s, c]),
                "frame_effect": [float(v) for v in rel.frame_effect[s, c]]}

    translation = worst[0] if ratio_kept[worst[0], 0] >= ratio_kept[worst[1], 1] else worst[1]
    return {
        "frame_reliability_delta0": rel.delta0,
        "frame_reliability_sd": [float(v) for v in sd],
        "frame_reliability_effect": [float(np.max(effect[kept].reshape(-1, 3)[:, a])) for a in range(3)],
        "frame_reliability_effect_sd": [float(ratio_kept[worst[a], a]) for a in range(3)],
        "frame_reliability_heading_sighting": sighting(int(worst[2])),
        "frame_reliability_translation_sighting": sighting(int(translation)),
        "frame_reliability_unchecked": bool(np.max(ratio_kept) > rel.delta0),
        "sighting_redundancy_min": float(np.min(numbers)),
        "sighting_redundancy_median": float(np.median(numbers)),
    }


def design_figures(*computations: Callable[[], dict]) -> dict:
    """The figures of ``computations`` (:func:`reliability_metrics`, the naming's) merged, or, if one fails (a
    solution that is not finite, an information matrix that is not positive definite: numpy's LinAlgError is a
    ValueError), ``reliability_unavailable``: why, in one line. The map is still the map: a run that took minutes (a
    chain, tens of them) is not lost for its diagnosis, and :func:`reliability_warning` says the figures are missing."""
    out: dict = {}
    try:
        for compute in computations:
            out |= compute()
    except (ValueError, FloatingPointError) as e:
        return {"reliability_unavailable": f"{type(e).__name__}: {e}"}
    return out


def reliability_warning(metrics: dict) -> str | None:
    """One line when ``metrics`` (:func:`reliability_metrics`'s) say the frame rests on single sightings
    (``frame_reliability_unchecked``): which sighting, the least error of it the data's test finds 80 % of the time,
    and how far that moves the frame against its σ (the heading's worst sighting if the heading passes δ₀ σ, else the
    translation's). The reason when the figures could not be computed (:func:`design_figures`). None otherwise (or
    without the figures)."""
    if "reliability_unavailable" in metrics:
        return (f"the map's reliability figures could not be computed ({metrics['reliability_unavailable']}): the map "
                "is written without them, and nothing says which sightings or namings its frame rests on")
    if not metrics.get("frame_reliability_unchecked"):
        return None
    ratio, delta0 = metrics["frame_reliability_effect_sd"], metrics["frame_reliability_delta0"]
    heading = ratio[2] > delta0
    s = metrics["frame_reliability_heading_sighting" if heading else "frame_reliability_translation_sighting"]
    unit = "rad" if s["component"] == "bearing" else "m"
    dx, dy, dtheta = s["frame_effect"]
    axis = "xy"[int(ratio[1] > ratio[0])]
    moved = (f"turn the frame by {abs(dtheta):.3f} rad, {ratio[2]:.1f} σ" if heading else
             f"shift the frame by ({dx:+.3f}, {dy:+.3f}) m, {max(ratio[0], ratio[1]):.1f} σ in {axis}")
    which = (f"landmark {s['landmark']}" if "landmark" in s else
             f"name {s['name']}" + (f", barcode {s['barcode']}" if "barcode" in s else ""))
    return (f"the map's frame rests on single sightings: in the {s['component']} of the sighting at "
            f"{s['time_s']:.2f} s ({which}; its redundancy {s['component_redundancy']:.2f}, "
            "0: nothing else checks it, 1: the others alone fix it) the least error the data's test finds 80 % of "
            f"the time (δ₀ {delta0:g}, α 0.1 %) is {s['minimal_bias']:.3f} {unit}, and it would {moved}: the "
            "frame's covariance does not hold it")
