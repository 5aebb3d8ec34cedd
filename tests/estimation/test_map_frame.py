"""A smoothed map's frame chosen by its data (estimation.map_frame): the frame of a later pose as a linear function
of the unknowns (against the exact map, hypothesis), the solution re-expressed in it (against the inverse of the
information of the problem whose gauge is that pose, by numerical differentiation), and the choice: the first pose
that no single sighting can move unseen, on a start that turns on the spot with one landmark in view at a time."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from estimation.frame_reliability import (
    DELTA_0,
    bias_in_sigmas,
    frame_functional,
    frame_problem,
    frame_reliability,
    reliability_metrics,
    sighting_redundancy,
)
from estimation.geometry import between, compose, dead_reckoning
from estimation.landmark_scores import rigid_functional
from estimation.landmark_smoother import (
    SightingOffset,
    Smoothed,
    normalised_residuals,
)
from estimation.map_frame import candidate_poses, checked_frame, image_errors, reframe, worst_effects_in_sd
from tests.estimation.frame_helpers import (
    LANDMARKS,
    TURN_FRAMES,
    glimpses_then_lap,
    solved,
    turn_and_lap,
)


def _in_frame_of(pose: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    return between(pose, np.column_stack([landmarks, np.zeros(len(landmarks))]))[:, :2]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n_landmarks=st.integers(2, 6), steps=st.integers(1, 6),
       width=st.sampled_from([3, 4, 5]))
def test_the_frame_of_a_later_pose_is_the_rigid_motion_of_the_map_as_that_pose_sees_it(seed, n_landmarks, steps,
                                                                                      width):
    """frame_functional(pose k) applied to a small change of the unknowns (poses 1..T, ``width`` columns each, then
    the landmarks) is the least-squares rigid motion, about pose k and along its axes, of the landmarks as pose k sees
    them: against the exact re-expression of the changed solution (second order small)."""
    rng = np.random.default_rng(seed)
    poses = np.vstack([np.zeros(3), np.column_stack([rng.uniform(-3, 3, (steps, 2)), rng.uniform(-np.pi, np.pi,
                                                                                                  steps)])])
    landmarks = rng.uniform(-6, 6, (n_landmarks, 2))
    gaps = np.hypot(*(landmarks[:, None] - landmarks[None]).transpose(2, 0, 1))[np.triu_indices(n_landmarks, 1)]
    assume(gaps.max() > 1.0)                 # a rotation needs points apart (the rigid fit's design well posed)
    solution = _solved_like(poses, landmarks)
    k = int(rng.integers(1, steps + 1))
    n_free = width * steps + 2 * n_landmarks
    functional = frame_functional(solution, np.ones(n_landmarks, bool), width, steps, n_free, k)
    step = 1e-6 * rng.standard_normal(n_free)
    moved_poses = poses.copy()
    moved_poses[1:] += step[:width * steps].reshape(steps, width)[:, :3]
    moved_landmarks = landmarks + step[width * steps:].reshape(-1, 2)
    before = _in_frame_of(poses[k], landmarks)
    after = _in_frame_of(moved_poses[k], moved_landmarks)
    expected = rigid_functional(before) @ (after - before).ravel()
    np.testing.assert_allclose(functional @ step, expected, rtol=1e-4, atol=1e-4 * np.abs(expected).max() + 1e-12)
    # pose 0 (the origin, fixed) is the landmarks' own rigid motion, as estimation.frame_reliability always had it
    at_origin = frame_functional(solution, np.ones(n_landmarks, bool), width, steps, n_free, 0)
    np.testing.assert_array_equal(at_origin[:, width * steps:], rigid_functional(landmarks))
    assert not at_origin[:, :width * steps].any()


def _solved_like(poses, landmarks) -> Smoothed:
    """A stand-in solution holding ``poses`` and ``landmarks`` (frame_functional reads nothing else)."""
    n = len(landmarks)
    return Smoothed(poses, landmarks, np.zeros((n, 2, 2)), np.zeros(0, int), np.zeros((0, 3, 3)), np.ones(0, bool),
                    0.0, 0, 0, True)


def _gauge_covariance(problem, solution, k: int) -> np.ndarray:
    """The inverse of JᵀJ of the problem whose gauge is pose k (unknowns: pose 0's and every pose's but k's as pose k
    sees them, then the landmarks as pose k sees them), J by central differences of the smoother's own normalised
    residuals (kept sightings): the covariance the re-expression must give, made without it."""
    t, n = problem.n_poses, len(solution.landmarks)
    seen_poses = between(solution.poses[k], solution.poses)
    seen_landmarks = _in_frame_of(solution.poses[k], solution.landmarks)
    free = [i for i in range(t + 1) if i != k]

    def residuals(y: np.ndarray) -> np.ndarray:
        q = seen_poses.copy()
        q[free] = y[:3 * t].reshape(t, 3)
        origin = q[0]
        poses = between(origin, q)
        landmarks = between(origin, np.column_stack([y[3 * t:].reshape(n, 2), np.zeros(n)]))[:, :2]
        odometry, sightings, _ = normalised_residuals(problem, dataclasses.replace(solution, poses=poses,
                                                                                   landmarks=landmarks))
        return np.concatenate([odometry.ravel(), sightings[solution.inliers].ravel()])

    y0 = np.concatenate([seen_poses[free].ravel(), seen_landmarks.ravel()])
    sighted = np.zeros(n, bool)
    sighted[problem.landmark_index[solution.inliers]] = True
    columns = np.concatenate([np.ones(3 * t, bool), np.repeat(sighted, 2)])   # a landmark never sighted: none
    h = 1e-6
    jac = np.column_stack([(residuals(y0 + h * e) - residuals(y0 - h * e)) / (2 * h)
                           for e in np.eye(len(y0))[columns]])
    covariance = np.full((len(y0), len(y0)), np.inf)
    covariance[np.ix_(columns, columns)] = np.linalg.inv(jac.T @ jac)
    return covariance


@pytest.mark.parametrize("k", [7, 60])
def test_the_solution_seen_from_a_later_pose_has_the_covariance_of_the_problem_fixed_there(k):
    """reframe: the poses and landmarks as pose k sees them (the same solution), and their covariances those of the
    problem whose gauge is pose k instead of pose 0 (its own information inverted, not the Jacobian's
    propagation): every landmark's joint covariance, every pose covariance the solution has, pose k's own left out."""
    problem = glimpses_then_lap(np.random.default_rng(3), 1)
    solution = solved(problem)
    framed = reframe(problem, solution, k)
    np.testing.assert_allclose(framed.solution.poses, between(solution.poses[k], solution.poses), atol=1e-12)
    np.testing.assert_allclose(compose(solution.poses[k], framed.solution.poses), solution.poses, atol=1e-12)
    np.testing.assert_allclose(framed.solution.landmarks, _in_frame_of(solution.poses[k], solution.landmarks),
                               atol=1e-12)
    expected = _gauge_covariance(problem, solution, k)
    t = problem.n_poses
    np.testing.assert_allclose(framed.joint_covariance, expected[3 * t:, 3 * t:], rtol=2e-4, atol=1e-9)
    idx = np.arange(len(solution.landmarks))
    marginals = framed.joint_covariance.reshape(len(idx), 2, len(idx), 2)[idx, :, idx, :]
    np.testing.assert_allclose(framed.solution.landmark_covariances, marginals)
    assert k not in framed.solution.covariance_poses
    assert len(framed.solution.covariance_poses) == len(solution.covariance_poses) - int(k in
                                                                                          solution.covariance_poses)
    position = {i: 3 * (i - 1 if i > k else i) for i in range(t + 1) if i != k}   # pose i's columns among the free
    for i, covariance in zip(framed.solution.covariance_poses, framed.solution.pose_covariances, strict=True):
        at = position[int(i)]
        np.testing.assert_allclose(covariance, expected[at:at + 3, at:at + 3], rtol=2e-4, atol=1e-10)
    # the frame's own reliability is that of the same functional on the re-expressed joint covariance
    frame = frame_problem(problem, solution, k)
    seen = np.unique(problem.landmark_index[solution.inliers])
    columns = np.column_stack([2 * seen, 2 * seen + 1]).ravel()
    rigid = rigid_functional(framed.solution.landmarks[seen])
    np.testing.assert_allclose(frame.covariance, rigid @ framed.joint_covariance[np.ix_(columns, columns)] @ rigid.T,
                               rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_start_that_turns_with_one_glimpse_at_a_time_gets_the_first_pose_several_sightings_check(seed):
    """One landmark seen from the first pose, then one glimpse every fifth frame of a 3 rad turn on the spot: each of
    those poses is tied to the map by its own glimpse alone, so the first sighting's frame is flagged (its worst
    effect above δ₀ σ, as reliability_metrics reports it) and so is every pose before the choice; the chosen pose is
    on the lap, where several landmarks are in view, and its frame passes (reliability_metrics at that pose says
    so too)."""
    problem = glimpses_then_lap(np.random.default_rng(seed), 1)
    solution = solved(problem)
    times = np.arange(1, problem.n_poses + 1) * 0.25
    ids = np.arange(len(LANDMARKS)) + 6
    first = reliability_metrics(problem, solution, times, ids)
    assert first["frame_reliability_unchecked"]
    choice = checked_frame(problem, solution)
    candidates = candidate_poses(problem, solution)
    assert list(candidates[:8]) == [0, 1, 5, 10, 15, 20, 25, 30]     # the first pose, then the turn's glimpses
    assert choice.found and choice.pose > TURN_FRAMES + 1
    assert candidates[choice.poses_tried - 1] == choice.pose
    np.testing.assert_allclose(choice.first_effect_sd, first["frame_reliability_effect_sd"], rtol=1e-8)
    assert np.all(choice.effect_sd <= DELTA_0)
    frame = frame_problem(problem, solution)
    in_sigmas = bias_in_sigmas(sighting_redundancy(problem, solution, frame.inverse))
    before = worst_effects_in_sd(problem, solution, frame, in_sigmas, candidates[:choice.poses_tried - 1],
                                 image_errors(problem, solution, frame))
    assert np.all(np.max(before, axis=1) > DELTA_0)
    chosen = reliability_metrics(problem, solution, times, ids, pose=choice.pose)
    assert not chosen["frame_reliability_unchecked"]      # the single sightings' part of the same test
    assert np.all(np.asarray(chosen["frame_reliability_effect_sd"]) <= choice.effect_sd + 1e-12)
    # the redundancies are the data's: the same whichever frame is asked about
    assert chosen["sighting_redundancy_min"] == first["sighting_redundancy_min"]


def test_a_first_frame_that_passes_is_kept_and_one_image_of_several_sightings_is_still_one_image():
    """Three landmarks in the first image and the lap straight after: each of those sightings is checked by the others
    and by the next images, and the single-sighting test keeps pose 0's frame. Their common error (the image's) is
    checked only by the odometry to the next image (0.026 rad per step of the lap, against 0.010 for the mean of three
    bearings): the images' test finds the first frame resting on one image, and the frame goes to the first pose
    that images on both sides check."""
    problem = glimpses_then_lap(np.random.default_rng(0), 3, lone_glimpses=False, turn_frames=0)
    solution = solved(problem)
    sightings_only = checked_frame(problem, solution, images=False)
    assert sightings_only.found and sightings_only.pose == 0 and sightings_only.poses_tried == 1
    np.testing.assert_array_equal(sightings_only.effect_sd, sightings_only.first_effect_sd)
    choice = checked_frame(problem, solution)
    assert choice.found and choice.pose > 1 and choice.first_effect_sd[2] > DELTA_0
    assert np.all(choice.effect_sd <= DELTA_0)


def test_no_candidate_within_the_search_passes_and_the_frame_stays_the_first_sighting_s():
    problem = glimpses_then_lap(np.random.default_rng(0), 1)
    solution = solved(problem)
    choice = checked_frame(problem, solution, max_candidates=5)
    assert not choice.found and choice.pose == 0 and choice.poses_tried == 5
    assert np.max(choice.effect_sd) > DELTA_0


def test_reframe_refuses_what_it_is_not_made_for():
    problem = glimpses_then_lap(np.random.default_rng(0), 1)
    solution = solved(problem)
    for pose in (0, problem.n_poses + 1):
        with pytest.raises(ValueError, match="not one of"):
            reframe(problem, solution, pose)
    offsets = dataclasses.replace(solution, sighting_offset=SightingOffset(0.03))
    with pytest.raises(ValueError, match="sighting offsets"):
        reframe(problem, offsets, 5)


def test_an_image_of_one_sighting_has_that_bearing_s_own_test_and_effect():
    """image_errors' alternative (one bias common to an image's bearings) for a pose with one kept sighting is that
    bearing's own: the same least detectable bias and the same effect on the frame."""
    problem = glimpses_then_lap(np.random.default_rng(1), 1)
    solution = solved(problem)
    frame = frame_problem(problem, solution)
    images = image_errors(problem, solution, frame)
    rel = frame_reliability(problem, solution)
    counts = np.bincount(problem.pose_index[solution.inliers], minlength=problem.n_poses + 1)
    lone = np.flatnonzero(counts[images.poses] == 1)
    assert len(lone) >= 6                                     # the first pose and the turn's glimpses at least
    sighting = np.array([np.flatnonzero(solution.inliers & (problem.pose_index == images.poses[i]))[0] for i in lone])
    np.testing.assert_allclose(images.minimal_bias[lone], rel.minimal_bias[sighting, 1], rtol=1e-6)
    effect = (images.directions @ frame.gain)[lone] * images.minimal_bias[lone, None]
    np.testing.assert_allclose(effect, rel.frame_effect[sighting, 1], rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1])
def test_two_sightings_of_one_image_do_not_check_its_common_error(seed):
    """Two landmarks in every image of the turn: each bearing is checked by the other, so the single-sighting test
    passes a pose of the turn, though one error of the image (its time stamp while turning) moves both alike and only
    the turn's odometry checks it. With the images' alternative the frame goes to the lap; an error of 0.05 rad shared
    by the turn's images then leaves it (where the turn's pose carries it into the frame's heading)."""
    problem = glimpses_then_lap(np.random.default_rng(seed), 1, per_glimpse=2, shared_bearing_error=0.05)
    solution = solved(problem)
    sightings_only = checked_frame(problem, solution, images=False)
    with_images = checked_frame(problem, solution)
    assert 0 < sightings_only.pose <= TURN_FRAMES + 1
    assert with_images.found and with_images.pose > TURN_FRAMES + 1
    seen = np.unique(problem.landmark_index[solution.inliers])
    truth = dead_reckoning(turn_and_lap(TURN_FRAMES))

    def heading_error(pose: int) -> float:
        framed = reframe(problem, solution, pose).solution.landmarks[seen]
        true = _in_frame_of(truth[pose], LANDMARKS[seen])
        return float(abs((rigid_functional(true) @ (framed - true).ravel())[2]))

    assert heading_error(with_images.pose) < heading_error(sightings_only.pose)
