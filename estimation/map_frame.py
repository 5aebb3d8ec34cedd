"""A smoothed map's frame chosen by its data: the first pose whose frame no single sighting can move unseen.

Why: a map's frame is a pose of the robot (its landmarks and path are given as that pose sees them) and by default it
is the pose at its first sighting (:mod:`estimation.dataset_slam`). What ties that pose to the map is whatever
sightings and increments join it to the landmarks. On MRCLAM robots 1 and 5, which start by turning on the spot with
one landmark in view at a time, that is the first glimpse alone: its bearing's redundancy is 0.05-0.20, an error of it
shows in no residual, and robot 1's is 0.067 rad off, which turns its whole map by 0.055 rad (sessions 41 (A), 42
(A)). :mod:`estimation.frame_reliability` says so from the problem's design; inflating the covariance does not mend
it (session 42 (A)), and dropping the glimpse makes the next one the lone tie. So the remedy asked of the frame's
definition: keep every sighting, and refer the map to a pose that several of them check.

The choice (``"checked"``): the first pose with a sighting of its own (:func:`candidate_poses`), in time order, whose
frame passes the reliability test of :func:`~estimation.frame_reliability.reliability_metrics`: no component of any
kept sighting, at its least detectable error ∇₀ (δ₀ = 4.13: the w-test at α 0.1 %, β 80 %), moves any of the frame's
coordinates (dx, dy, dθ) by more than δ₀ of its σ (Baarda's B method, one δ₀ for the data's test and the frame's).
The frame of pose k is the landmarks' least-squares rigid motion about pose k as pose k sees them
(:func:`~estimation.frame_reliability.frame_functional`), a linear function of the smoother's unknowns, so each
candidate costs one solve with three right-hand sides on the factorisation the reliability figures make anyway (the
redundancies are the data's, the same for every frame). No truth is read. If no candidate within ``max_candidates``
passes, the frame stays the first sighting's and the choice says so.

One image, one error: the sightings of one pose come from one camera image, and while the robot turns an error of
that image's time stamp (MRCLAM's camera repeats a stale image's readings while the robot turns: robot 5 at 13.16-13.46
s, its bearings 0.05-0.09 rad off together) moves all their bearings alike. Two sightings of one image then check each
other in the single-sighting test while their common error goes unseen (robot 5's pose at 13.32 s passed it and turned
the map 0.049 rad, 5 σ). So the test also takes, per image, the alternative of one bias common to its bearings
(:func:`image_errors`: Baarda's test of a specified bias vector), at its least detectable size; for an image of one
sighting it is that bearing's own test.

Re-expressing the solution in pose k's frame is a change of gauge, not of the solution: the smoother's cost has no
prior on pose 0, so its MAP poses and landmarks seen from pose k are exactly the map pose k would give; the
covariances follow by the Jacobian of (x ↦ x as pose k sees it) applied to the joint covariance of x and pose k
(exact for the linearised problem: the same as fixing pose k instead of pose 0). That needs H⁻¹'s columns at pose k,
one more solve.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from .frame_reliability import (
    DELTA_0,
    QUARTER_TURN,
    FrameProblem,
    bias_in_sigmas,
    frame_functional,
    frame_problem,
    sighting_redundancy,
)
from .geometry import between
from .landmark_smoother import LandmarkLogProblem, Smoothed, image_whitening

FRAMES = ("first-sighting", "checked")
FIRST_SIGHTING, CHECKED = FRAMES
_CANDIDATES_PER_SOLVE = 32      # candidate poses whose three right-hand sides share one solve
_NO_REDUNDANCY = 1e-12          # vᵀ R v below this share of vᵀ v: nothing checks the image's common error


@dataclass(frozen=True)
class FrameChoice:
    """Which pose's frame :func:`checked_frame` chose: ``pose`` (0: the first sighting's), whether it passes the test
    (``found``; False: no candidate within the search passed and the frame stayed pose 0's), the candidates tried
    (``poses_tried``), and the
    worst effect in σ (3,) on (x, y, heading) of the chosen frame and of pose 0's (``first_effect_sd``)."""

    pose: int
    found: bool
    poses_tried: int
    effect_sd: np.ndarray
    first_effect_sd: np.ndarray
    delta0: float


@dataclass(frozen=True)
class ImageErrors:
    """One error common to every bearing of one image (the sightings of one pose): ``poses`` (P,) the poses with a
    kept sighting, ``directions`` (P, n) a_i = Σ_r J_r / σ_r over the pose's kept bearing rows r of the whitened
    Jacobian (what a bias of 1 rad on all of them adds to J δ), ``minimal_bias`` (P,) the least such bias the
    w-test of that alternative finds with probability β, δ₀ / √(vᵀ R v) (rad; inf where nothing checks it)."""

    poses: np.ndarray
    directions: sp.csr_matrix
    minimal_bias: np.ndarray


def image_errors(problem: LandmarkLogProblem, solution: Smoothed, frame: FrameProblem,
                 delta0: float = DELTA_0) -> ImageErrors:
    """:class:`ImageErrors` of ``solution``. The alternative is Baarda's for a specified bias vector: v (whitened,
    1/σ_r on the pose's bearing rows; with one error per image in the model, W (1/σ_r) by its whitening W:
    :func:`~estimation.landmark_smoother.image_whitening`), its test w = vᵀ ê / √(vᵀ R v), noncentrality
    b √(vᵀ R v), with vᵀ R v = vᵀ v − a H⁻¹ aᵀ. For a pose with one sighting it is that bearing's own ∇₀ and effect."""
    kept = np.flatnonzero(solution.inliers)
    pose_of = problem.pose_index[kept]
    poses, which = np.unique(pose_of, return_inverse=True)
    weights = 1.0 / problem.bearing_sigmas
    whitening = image_whitening(problem, solution.inliers)
    if whitening is not None:   # one error per image in the model: the bias's direction among the whitened rows
        weights = whitening @ weights
    weights = weights[kept]
    rows = 3 * problem.n_poses + 2 * kept + 1
    summing = sp.csr_matrix((weights, (which, np.arange(len(kept)))), shape=(len(poses), len(kept)))
    directions = sp.csr_matrix(summing @ frame.inverse.jac[rows])
    own = np.bincount(which, weights ** 2, minlength=len(poses))                # vᵀ v
    checked = own - frame.inverse.quadratic_forms(directions)                   # vᵀ R v
    with np.errstate(divide="ignore", invalid="ignore"):
        minimal = np.where(checked > _NO_REDUNDANCY * own, delta0 / np.sqrt(np.maximum(checked, 1e-300)), np.inf)
    return ImageErrors(poses, directions, minimal)


def worst_effects_in_sd(problem: LandmarkLogProblem, solution: Smoothed, frame: FrameProblem,
                        in_sigmas: np.ndarray, poses: np.ndarray, images: ImageErrors | None = None) -> np.ndarray:
    """(P, 3) for each pose of ``poses`` the most one component's ∇₀ of one kept sighting moves each coordinate of that
    pose's frame, in units of the frame's σ (the figure ``frame_reliability_effect_sd`` reports for pose 0).
    ``frame``: any :class:`~estimation.frame_reliability.FrameProblem` of ``solution`` (its factorisation is used);
    ``in_sigmas`` (S, 2): :func:`~estimation.frame_reliability.bias_in_sigmas` of the sightings' redundancy.
    ``images``: also each image's common bearing error at its least detectable size (:func:`image_errors`)."""
    t, n_free = problem.n_poses, int(frame.free.sum())
    kept = np.flatnonzero(solution.inliers)
    rows = 3 * t + 2 * kept
    jac = frame.inverse.jac[np.column_stack([rows, rows + 1]).ravel()]
    scale = in_sigmas[kept].reshape(-1, 1)                                       # (2K, 1) ∇₀ / σ per row
    out = np.zeros((len(poses), 3))
    for start in range(0, len(poses), _CANDIDATES_PER_SOLVE):
        batch = poses[start:start + _CANDIDATES_PER_SOLVE]
        functional = np.vstack([frame_functional(solution, frame.seen, frame.width, t, n_free, int(k))
                                for k in batch])                                # (3P, n)
        gain = frame.inverse.factor.solve(functional.T)                          # (n, 3P)
        sd = np.sqrt(np.einsum("ij,ji->i", functional, gain))                   # (3P,)
        per_unit = jac @ gain                                                    # (2K, 3P)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(per_unit == 0, 0.0, np.abs(per_unit * scale) / sd)
            if images is not None:
                per_image = images.directions @ gain                            # (P, 3P) per rad
                image_ratio = np.where(per_image == 0, 0.0,
                                       np.abs(per_image * images.minimal_bias[:, None]) / sd)
                ratio = np.vstack([ratio, image_ratio])
        out[start:start + len(batch)] = ratio.max(axis=0).reshape(-1, 3)
    return out


def candidate_poses(problem: LandmarkLogProblem, solution: Smoothed) -> np.ndarray:
    """The poses a frame may be chosen at, in time order: pose 0 (the first sighting's frame, the default) and every
    pose with a kept sighting of its own. A pose that sees nothing is tied to the map through its increments only:
    its frame can pass the test by being vague (its σ large beside any one sighting's effect), which is not what a
    checked frame is for."""
    return np.unique(np.append(0, problem.pose_index[np.asarray(solution.inliers, bool)]))


def checked_frame(problem: LandmarkLogProblem, solution: Smoothed, *, delta0: float = DELTA_0,
                  max_candidates: int | None = None, images: bool = True) -> FrameChoice:
    """The first of the :func:`candidate_poses` of ``solution`` (at most ``max_candidates`` of them, None: all) whose
    frame no kept sighting's ∇₀ moves by more than ``delta0`` of its σ on any coordinate, nor (``images``, the
    default) any image's common bearing error at its least detectable size (:func:`image_errors`; see the module
    docstring). Needs a frame (two landmarks with a kept sighting; ValueError otherwise)."""
    frame = frame_problem(problem, solution)
    in_sigmas = bias_in_sigmas(sighting_redundancy(problem, solution, frame.inverse), delta0)
    common = image_errors(problem, solution, frame, delta0) if images else None
    candidates = candidate_poses(problem, solution)
    if max_candidates is not None:
        candidates = candidates[:max(int(max_candidates), 1)]
    first = None
    for start in range(0, len(candidates), _CANDIDATES_PER_SOLVE):
        poses = candidates[start:start + _CANDIDATES_PER_SOLVE]
        worst = worst_effects_in_sd(problem, solution, frame, in_sigmas, poses, common)
        if first is None:
            first = worst[0]
        passing = np.flatnonzero(np.all(worst <= delta0, axis=1))
        if len(passing):
            k = int(passing[0])
            return FrameChoice(int(poses[k]), True, start + k + 1, worst[k], first, float(delta0))
    return FrameChoice(0, False, len(candidates), first, first, float(delta0))


@dataclass(frozen=True)
class Reframed:
    """A smoothed solution as pose ``pose`` sees it: ``solution`` (its poses (T + 1, 3) with pose ``pose`` at the
    origin, landmarks (L, 2), their marginal covariances and the pose covariances in that frame; pose ``pose`` itself
    left out of ``covariance_poses``, exact there) and the landmarks' ``joint_covariance`` (2L, 2L) in that frame
    (inf on the rows of a landmark with no kept sighting), as
    :func:`~estimation.landmark_smoother.joint_landmark_covariance` gives it in pose 0's."""

    pose: int
    solution: Smoothed
    joint_covariance: np.ndarray


def reframe(problem: LandmarkLogProblem, solution: Smoothed, pose: int,
            frame: FrameProblem | None = None) -> Reframed:
    """``solution`` as pose ``pose`` (1..T) sees it (see the module docstring). ``frame``: its
    :class:`~estimation.frame_reliability.FrameProblem` if made already (its factorisation is used). Not with
    sighting offsets (the chain's smoothings): ValueError."""
    if solution.sighting_offset is not None and solution.sighting_offset.on:
        raise ValueError("a chosen frame is not made for a solution with sighting offsets (the chain's)")
    t = problem.n_poses
    if not 1 <= pose <= t:
        raise ValueError(f"pose {pose} is not one of the solution's 1..{t}")
    frame = frame_problem(problem, solution) if frame is None else frame
    width, seen = frame.width, frame.seen
    at = width * (pose - 1)
    unit = np.zeros((int(frame.free.sum()), 3))
    unit[at + np.arange(3), np.arange(3)] = 1.0
    column = frame.inverse.factor.solve(unit)                                    # H⁻¹'s columns at pose k (n, 3)
    own = column[at:at + 3]                                                      # Σ_kk
    x, y, theta = solution.poses[pose]
    c, s = np.cos(theta), np.sin(theta)
    rotation_t = np.array([[c, s], [-s, c]])                                     # Rᵀ

    # the landmarks: m_j = Rᵀ (l_j − p_k); δm = A δl + B δx_k, A = Rᵀ (block diagonal), B_j = [−Rᵀ, −J m_j]
    n_seen = int(seen.sum())
    seen_from = (solution.landmarks - [x, y]) @ rotation_t.T
    a = np.kron(np.eye(n_seen), rotation_t)
    b = np.zeros((2 * n_seen, 3))
    b[:, :2] = np.tile(-rotation_t, (n_seen, 1))
    b[:, 2] = -(seen_from[seen] @ QUARTER_TURN.T).ravel()
    lm = slice(width * t, width * t + 2 * n_seen)
    cross = a @ column[lm] @ b.T
    joint_seen = a @ frame.inverse.dense @ a.T + cross + cross.T + b @ own @ b.T
    joint_seen = 0.5 * (joint_seen + joint_seen.T)
    n = len(solution.landmarks)
    keep = np.repeat(seen, 2)
    joint = np.full((2 * n, 2 * n), np.inf)
    joint[np.ix_(keep, keep)] = joint_seen
    marginals = np.full((n, 2, 2), np.inf)
    idx = np.arange(n_seen)
    marginals[seen] = joint_seen.reshape(n_seen, 2, n_seen, 2)[idx, :, idx, :]

    # the poses: Δ_i = (Rᵀ (p_i − p_k), θ_i − θ_k); δΔ = A_i δx_i + B_i δx_k, A_i = diag(Rᵀ, 1),
    # B_i = [[−Rᵀ, −J Δ_i,xy], [0, 0, −1]]
    poses = between(solution.poses[pose], solution.poses)
    which = np.asarray(solution.covariance_poses)
    keep_poses = which != pose
    which, covariances = which[keep_poses], np.asarray(solution.pose_covariances)[keep_poses]
    a_pose = np.eye(3)
    a_pose[:2, :2] = rotation_t
    b_pose = np.zeros((len(which), 3, 3))
    b_pose[:, :2, :2] = -rotation_t
    b_pose[:, :2, 2] = -(poses[which, :2] @ QUARTER_TURN.T)
    b_pose[:, 2, 2] = -1.0
    rows = width * (which[:, None] - 1) + np.arange(3)
    with_k = column[rows]                                                        # (P, 3, 3) Σ_ik
    crossed = a_pose @ with_k @ b_pose.transpose(0, 2, 1)
    pose_cov = (a_pose @ covariances @ a_pose.T + crossed + crossed.transpose(0, 2, 1)
                + b_pose @ own @ b_pose.transpose(0, 2, 1))
    pose_cov = 0.5 * (pose_cov + pose_cov.transpose(0, 2, 1))
    out = replace(solution, poses=poses, landmarks=seen_from, landmark_covariances=marginals,
                  covariance_poses=which, pose_covariances=pose_cov)
    return Reframed(pose, out, joint)
