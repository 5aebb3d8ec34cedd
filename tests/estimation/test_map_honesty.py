"""Split scores (estimation/map_honesty.py): a run of a landmark's sightings that disagrees with the rest of it, seen
without the true identities, on simulated logs with a wrong sighting injected where only odometry holds the map."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from estimation import chi2
from estimation.geometry import between, dead_reckoning, wrap_angle
from estimation.landmark_smoother import (
    LandmarkLogProblem,
    landmarks_from_first_sightings,
    normalised_residuals,
    smooth,
)
from estimation.map_honesty import (
    Run,
    flagged_landmarks,
    flagged_runs,
    jumping_landmarks,
    self_covisible_frames,
    sighting_jumps,
    sighting_runs,
    sighting_times,
    split_scores,
    split_threshold,
    two_point_split,
)

SIGMA_R, SIGMA_B = 0.05, 0.02
STEPS, LAP = 300, 120                 # 1 s a step, a 2 m circle in 120 steps: 2.5 laps
BLIND = ((140, 150), (170, 180))      # steps without sightings, the odometry loose across them
STRETCH = (150, 170)                  # between them: the landmarks seen get names of their own (unmerged chain names)


def stretch_log(seed: int, wrong_offset: np.ndarray | None = None, gap_sd: float = 0.3):
    """A robot driving a 2 m circle among 8 landmarks, its odometry and sightings drawn from the model, with a
    stretch (steps 150–169) seen only under names of its own and held by nothing but odometry that is loose across the
    blind steps around it (σ ``gap_sd`` in x, y and heading over each). With ``wrong_offset`` (2,), one more sighting
    from step 139 (a pose the map knows) of a point that far from the stretch's first landmark, under that landmark's
    stretch name: robot 3's wrong sighting (MRCLAM dataset 2, 1252.6 s). Returns the problem, the injected sighting's
    index (None without) and the true landmark of each landmark index."""
    rng = np.random.default_rng(seed)
    step = np.array([2 * np.pi * 2.0 / LAP, 0.0, 2 * np.pi / LAP])
    truth = dead_reckoning(np.tile(step, (STEPS, 1)))
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    landmarks = np.column_stack([3.2 * np.cos(angles), 2.0 + 3.2 * np.sin(angles)])
    trans = np.hypot(step[0], step[1])
    variance = np.tile(2e-3 * trans, (STEPS, 3))
    blind = np.zeros(STEPS + 1, bool)
    for a, b in BLIND:
        blind[a:b] = True
        variance[a - 1:b - 1] = gap_sd ** 2 / (b - a)
    measured = between(truth[:-1], truth[1:]) + rng.standard_normal((STEPS, 3)) * np.sqrt(variance)
    pose_index, names, ranges, bearings = [], [], [], []
    for k in np.flatnonzero(~blind[1:]) + 1:
        d = landmarks - truth[k, :2]
        r = np.hypot(d[:, 0], d[:, 1])
        b = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - truth[k, 2])
        visible = np.flatnonzero((np.abs(b) < 0.8) & (r < 5.0))
        pose_index += [k] * len(visible)
        names += list(visible + (8 if STRETCH[0] <= k < STRETCH[1] else 0))
        ranges += list(r[visible] + SIGMA_R * rng.standard_normal(len(visible)))
        bearings += list(b[visible] + SIGMA_B * rng.standard_normal(len(visible)))
    injected = None
    if wrong_offset is not None:
        name = min(n for n in names if n >= 8)
        d = landmarks[name - 8] + wrong_offset - truth[BLIND[0][0] - 1, :2]
        pose_index.append(BLIND[0][0] - 1)
        names.append(name)
        ranges.append(np.hypot(d[0], d[1]) + SIGMA_R * rng.standard_normal())
        bearings.append(wrap_angle(np.arctan2(d[1], d[0]) - truth[BLIND[0][0] - 1, 2])
                        + SIGMA_B * rng.standard_normal())
        injected = len(names) - 1
    used, landmark_index = np.unique(names, return_inverse=True)
    s = len(ranges)
    problem = LandmarkLogProblem(measured, variance, np.array(pose_index), landmark_index, np.array(ranges),
                                 np.array(bearings), np.full(s, SIGMA_R), np.full(s, SIGMA_B),
                                 increment_seconds=np.ones(STEPS))
    return problem, injected, landmarks[used % 8]


def solved(problem: LandmarkLogProblem):
    poses = dead_reckoning(problem.increments)
    return smooth(problem, poses, landmarks_from_first_sightings(problem, poses))


def cost(problem: LandmarkLogProblem, solution) -> float:
    odometry, sightings, extra = normalised_residuals(problem, solution)
    return float(np.sum(odometry ** 2) + np.sum(sightings[solution.inliers] ** 2) + np.sum(extra ** 2))


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2 ** 16), pick=st.integers(0, 10 ** 6))
def test_a_split_score_is_the_cost_drop_of_re_smoothing_with_the_run_as_a_landmark_of_its_own(seed, pick):
    problem, _, _ = stretch_log(seed)
    solution = solved(problem)
    runs = sighting_runs(problem, solution, 5.0)
    scores = split_scores(problem, solution, runs)
    run = runs[pick % len(runs)]
    index = problem.landmark_index.copy()
    index[run.sightings] = problem.n_landmarks
    split = dataclasses.replace(problem, landmark_index=index)
    resolved = smooth(split, solution.poses, np.vstack([solution.landmarks, solution.landmarks[run.landmark]]))
    assume(np.array_equal(resolved.inliers, solution.inliers))      # the same sightings kept: one cost for both
    drop = cost(problem, solution) - cost(split, resolved)
    assert scores[pick % len(runs)] == pytest.approx(drop, rel=0.05, abs=0.05)


def test_a_wrong_sighting_that_ties_a_loose_stretch_to_the_map_has_the_top_split_score_and_is_flagged():
    flagged, honest_flags = 0, 0
    for seed in range(12):
        problem, injected, _ = stretch_log(seed, np.array([0.0, 1.2]))
        solution = solved(problem)
        assert solution.inliers[injected]            # kept: the stretch bends to fit it, as robot 3's did
        runs = sighting_runs(problem, solution, 5.0)
        scores = split_scores(problem, solution, runs)
        wrong = problem.landmark_index[injected]
        top = runs[int(np.nanargmax(scores))]
        assert top.landmark == wrong
        flagged += np.nanmax(scores) > split_threshold(len(runs))
        honest, _, _ = stretch_log(seed)
        honest_solution = solved(honest)
        honest_runs = sighting_runs(honest, honest_solution, 5.0)
        honest_flags += np.nanmax(split_scores(honest, honest_solution, honest_runs)) > split_threshold(
            len(honest_runs))
    assert flagged >= 10                             # measured 11 of 12 (the 12th: score 12.9, threshold 15.5)
    assert honest_flags == 0


def test_the_per_name_test_flags_the_wrong_name_against_its_own_runs_only():
    problem, injected, _ = stretch_log(0, np.array([0.0, 1.2]))
    solution = solved(problem)
    runs = sighting_runs(problem, solution, 5.0)
    scores = split_scores(problem, solution, runs)
    flagged = flagged_landmarks(runs, scores, len(solution.landmarks))
    assert flagged.shape == (len(solution.landmarks),)
    assert flagged[problem.landmark_index[injected]]
    for landmark in np.flatnonzero(flagged):        # each flag has a run beyond χ²₂ at 1 − α/k, k its own runs
        own = [s for r, s in zip(runs, scores, strict=True) if r.landmark == landmark]
        assert np.nanmax(own) > split_threshold(len(own))
    honest, _, _ = stretch_log(0)
    honest_solution = solved(honest)
    honest_runs = sighting_runs(honest, honest_solution, 5.0)
    assert not flagged_landmarks(honest_runs, split_scores(honest, honest_solution, honest_runs),
                                 len(honest_solution.landmarks)).any()


def without_sightings(problem: LandmarkLogProblem, drop: np.ndarray) -> LandmarkLogProblem:
    keep = np.ones(len(problem.ranges), bool)
    keep[drop] = False
    return dataclasses.replace(problem, pose_index=problem.pose_index[keep],
                               landmark_index=problem.landmark_index[keep], ranges=problem.ranges[keep],
                               bearings=problem.bearings[keep],
                               range_sigmas=problem.range_sigmas[keep], bearing_sigmas=problem.bearing_sigmas[keep])


def landmark_nees(solution, truth: np.ndarray, index: np.ndarray) -> np.ndarray:
    error = solution.landmarks[index] - truth[index]
    return np.einsum("li,li->l", error, np.linalg.solve(solution.landmark_covariances[index], error[..., None])[..., 0])


@pytest.mark.parametrize("seed", range(6))
def test_taking_the_flagged_runs_out_of_their_names_makes_the_bent_stretch_honest(seed):
    problem, injected, truth = stretch_log(seed, np.array([0.0, 1.2]))
    solution = solved(problem)
    runs = sighting_runs(problem, solution, 5.0)
    out = flagged_runs(runs, split_scores(problem, solution, runs))
    taken = np.concatenate([runs[i].sightings for i in np.flatnonzero(out)])
    wrong = problem.landmark_index[injected]
    assert injected in taken                        # the wrong sighting's run goes, its name's stretch run stays
    in_stretch = (problem.pose_index >= STRETCH[0]) & (problem.pose_index < STRETCH[1])
    assert not np.isin(np.flatnonzero(in_stretch & (problem.landmark_index == wrong)), taken).any()
    stretch = np.unique(problem.landmark_index[in_stretch])
    bound = chi2.ppf(0.95, 2)
    assert landmark_nees(solution, truth, stretch).max() > 10 * bound     # bent to fit it: confidently wrong
    rest = without_sightings(problem, taken)
    resolved = solved(rest)
    assert np.all(landmark_nees(resolved, truth, stretch) < bound)          # measured ≤ 4.6 on seeds 0-11
    rest_runs = sighting_runs(rest, resolved, 5.0)
    assert not flagged_runs(rest_runs, split_scores(rest, resolved, rest_runs)).any()


@settings(max_examples=60, deadline=None)
@given(sizes=st.lists(st.tuples(st.integers(0, 4), st.integers(1, 30)), min_size=1, max_size=20),
       raw=st.lists(st.one_of(st.floats(0.0, 60.0), st.just(float("nan"))), min_size=20, max_size=20),
       alpha=st.floats(0.001, 0.2))
def test_a_name_keeps_its_largest_run_and_loses_every_other_run_beyond_its_own_threshold(sizes, raw, alpha):
    runs = [Run(landmark, np.arange(size), 0.0, 1.0) for landmark, size in sizes]
    scores = np.array(raw[:len(runs)])
    out = flagged_runs(runs, scores, alpha)
    landmarks = {run.landmark for run in runs}
    flagged_names = flagged_landmarks(runs, scores, 5, alpha)
    for landmark in landmarks:
        mine = [i for i, run in enumerate(runs) if run.landmark == landmark]
        largest = max(mine, key=lambda i: (len(runs[i].sightings), -i))
        assert not out[largest]                     # the name keeps its largest run (of equals, the first)
        threshold = split_threshold(len(mine), alpha)
        for i in mine:
            if i != largest:
                assert out[i] == (np.isfinite(scores[i]) and scores[i] > threshold)
        if any(out[i] for i in mine):
            assert flagged_names[landmark]          # a run taken out is a flag of the per-name screen
    with pytest.raises(ValueError, match="one score a run"):
        flagged_runs(runs, np.zeros(len(runs) + 1))


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2 ** 16), floor=st.floats(0.005, 0.5))
def test_an_offset_floor_lowers_every_score_and_leaves_a_metre_off_run_flagged(seed, floor):
    problem, injected, _ = stretch_log(seed, np.array([0.0, 1.2]))
    solution = solved(problem)
    assume(solution.inliers[injected])
    runs = sighting_runs(problem, solution, 5.0)
    exact = split_scores(problem, solution, runs)
    floored = split_scores(problem, solution, runs, floor_m=floor)
    assert np.array_equal(split_scores(problem, solution, runs, floor_m=0.0), exact)
    assert np.all(floored <= exact + 1e-9)
    wrong = problem.landmark_index[injected]
    mine = [i for i, r in enumerate(runs) if r.landmark == wrong]
    if floor <= 0.05 and exact[mine].max() > 2 * split_threshold(len(runs)):   # a few cm of floor against a metre
        assert floored[mine].max() > split_threshold(len(runs))


def test_runs_are_cut_at_gaps_and_a_landmark_of_one_run_is_not_tested():
    problem, injected, _ = stretch_log(3, np.array([0.0, 1.2]))
    solution = solved(problem)
    times = sighting_times(problem)
    runs = sighting_runs(problem, solution, 5.0)
    for run in runs:
        assert np.all(np.diff(times[run.sightings]) <= 5.0)
        assert np.all(solution.inliers[run.sightings])
        assert np.all(problem.landmark_index[run.sightings] == run.landmark)
    by_landmark = {}
    for run in runs:
        by_landmark.setdefault(run.landmark, []).append(run)
    assert all(len(v) >= 2 for v in by_landmark.values())
    wrong = problem.landmark_index[injected]
    assert [len(r.sightings) for r in by_landmark[wrong]][0] == 1       # the injected sighting alone, then the rest
    stretch_only = set(problem.landmark_index[(problem.pose_index >= STRETCH[0])
                                              & (problem.pose_index < STRETCH[1])]) - {wrong}
    assert not stretch_only & set(by_landmark)       # the stretch's other names: one run each, nothing to test


def test_a_run_that_is_all_of_its_landmark_gets_no_score_and_bad_arguments_are_refused():
    problem, _, _ = stretch_log(1)
    solution = solved(problem)
    whole = np.flatnonzero(solution.inliers & (problem.landmark_index == 0))
    assert np.isnan(split_scores(problem, solution, [Run(0, whole, 0.0, 1.0)])[0])
    assert split_scores(problem, solution, []).shape == (0,)
    with pytest.raises(ValueError, match="gap"):
        sighting_runs(problem, solution, -1.0)
    with pytest.raises(ValueError, match="floor"):
        split_scores(problem, solution, sighting_runs(problem, solution, 5.0), floor_m=float("nan"))
    with pytest.raises(ValueError, match="n_tests"):
        split_threshold(0)
    assert split_threshold(1) == pytest.approx(9.2103, abs=1e-3)


def twin_log(seed: int, separation: float, direction: float, *, one_name: bool = True):
    """The 2 m circle among 8 landmarks (:func:`stretch_log`'s, no blind steps), plus a ninth point ``separation`` m
    from landmark 0 towards ``direction`` (rad); each sighting missed with probability 0.3, so the two are sighted
    together in some frames and alone in others. The sensor's σ (0.02 m, 0.005 rad) is far below the model's (0.05
    m, 0.1 rad), as MRCLAM's is below its inflated bearing σ. With ``one_name`` the ninth point's sightings are named
    landmark 0 (a chained name that holds two posts). Returns the problem and each sighting's true point (0..8)."""
    rng = np.random.default_rng(seed)
    step = np.array([2 * np.pi * 2.0 / LAP, 0.0, 2 * np.pi / LAP])
    truth = dead_reckoning(np.tile(step, (STEPS, 1)))
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    landmarks = np.column_stack([3.2 * np.cos(angles), 2.0 + 3.2 * np.sin(angles)])
    landmarks = np.vstack([landmarks, landmarks[0] + separation * np.array([np.cos(direction), np.sin(direction)])])
    variance = np.tile(2e-3 * np.hypot(step[0], step[1]), (STEPS, 3))
    measured = between(truth[:-1], truth[1:]) + rng.standard_normal((STEPS, 3)) * np.sqrt(variance)
    pose_index, points, ranges, bearings = [], [], [], []
    for k in range(1, STEPS + 1):
        d = landmarks - truth[k, :2]
        r = np.hypot(d[:, 0], d[:, 1])
        b = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - truth[k, 2])
        visible = np.flatnonzero((np.abs(b) < 0.8) & (r < 5.0) & (rng.random(len(r)) > 0.3))
        pose_index += [k] * len(visible)
        points += list(visible)
        ranges += list(r[visible] + 0.02 * rng.standard_normal(len(visible)))
        bearings += list(b[visible] + 0.005 * rng.standard_normal(len(visible)))
    points = np.array(points)
    names = np.where(points == 8, 0, points) if one_name else points
    s = len(ranges)
    problem = LandmarkLogProblem(measured, variance, np.array(pose_index), names, np.array(ranges),
                                 np.array(bearings), np.full(s, 0.05), np.full(s, 0.1),
                                 increment_seconds=np.ones(STEPS))
    return problem, points


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2 ** 16), separation=st.floats(0.5, 1.5), direction=st.floats(-np.pi, np.pi))
def test_a_name_sighted_twice_in_one_frame_is_found_and_split_into_its_two_points(seed, separation, direction):
    problem, points = twin_log(seed, separation, direction)
    both = set(problem.pose_index[points == 0]) & set(problem.pose_index[points == 8])
    assume(len(both) >= 1)
    frames = self_covisible_frames(problem)
    assert frames[0] == len(both)                    # the frames that saw both points, and only on the shared name
    assert not frames[1:].any()
    solution = solved(problem)
    second = two_point_split(problem, solution, 0)
    truth = points[problem.landmark_index == 0] == 8
    agree = max(np.mean(second == truth), np.mean(second != truth))     # which part is "second" does not matter
    assert agree >= 0.95                             # measured ≥ 0.99 in 20 draws (0.90 with the whole name's means)


def test_an_honest_map_has_no_self_covisible_name_and_a_split_needs_one():
    problem, _ = twin_log(4, 0.8, 1.0, one_name=False)
    assert not self_covisible_frames(problem).any()
    with pytest.raises(ValueError, match="cannot be one point"):
        two_point_split(problem, solved(problem), 0)


# The jump tests' α is a false-alarm rate: an honest map is flagged with probability ≤ α (Bonferroni over its J
# pairs), so "no honest name jumps at α 0.01", asserted on every draw, is false on about 1 draw in 750 (measured: 1
# of 754 draws at separation 0.5; 2 of 4000 honest maps at 0.5–1.5). Seed 1794 at separation 0.5, direction 2.0 is
# one: landmark 2's kept sightings at poses 278 → 279 jump 30.7 and 30.4 against 20.8 and 20.9 (J 335 and 345) with
# and without the twin's one name, from twin_log's own draws (their ranges 3.3 σ long then 2.8 σ short, the
# odometry's heading 3.8 σ off in that step): the sensor and odometry the model describes. So the hypothesis tests
# hold honest names at α RARE (a chance failure ≤ 2·RARE an example: the statistic's tail is below χ²₂'s), and the
# rate at α 0.01 is asserted on fixed seeds (test_an_honest_map_jumps_no_more_often_than_alpha).
RARE = 1e-6


def jumps_beyond(problem: LandmarkLogProblem, solution, alpha: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sighting_jumps` under :func:`twin_log`'s sensor (0.02 m, 0.005 rad, no correlation), and which are
    beyond χ²₂ at 1 − α/J."""
    pairs, jump = sighting_jumps(problem, solution, np.full(len(problem.ranges), 0.02), 0.005, 0.0, 0.0, gap_s=1.0)
    return pairs, jump > chi2.isf(alpha / len(jump), 2)


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2 ** 16), separation=st.floats(0.5, 1.5), direction=st.floats(-np.pi, np.pi))
def test_jumps_beyond_the_sensor_s_own_noise_are_the_steps_between_two_points_of_one_name(
        seed, separation, direction):
    problem, points = twin_log(seed, separation, direction)
    pairs, beyond = jumps_beyond(problem, solved(problem))
    assert np.all(problem.landmark_index[pairs[:, 0]] == problem.landmark_index[pairs[:, 1]])
    assert np.all(problem.pose_index[pairs[:, 1]] == problem.pose_index[pairs[:, 0]] + 1)   # 1 s a step: the next
    switch = points[pairs[:, 0]] != points[pairs[:, 1]]
    assume(switch.any())
    assert beyond[switch].mean() >= 0.9             # measured: every step between the points in 8 draws
    assert beyond[~switch].mean() <= 0.02           # measured: none
    honest, _ = twin_log(seed, separation, direction, one_name=False)
    assert not jumps_beyond(honest, solved(honest), RARE)[1].any()      # at α 0.01 false on 1 draw in ~750 (RARE)


def test_two_points_split_by_their_jumps_alone():
    problem, points = twin_log(7, 1.0, 0.5)
    both = np.intersect1d(problem.pose_index[points == 0], problem.pose_index[points == 8])
    keep = ~((points == 8) & np.isin(problem.pose_index, both))     # the frames that saw both lose the twin's sighting
    single = dataclasses.replace(
        problem, pose_index=problem.pose_index[keep], landmark_index=problem.landmark_index[keep],
        ranges=problem.ranges[keep], bearings=problem.bearings[keep], range_sigmas=problem.range_sigmas[keep],
        bearing_sigmas=problem.bearing_sigmas[keep])
    assert not self_covisible_frames(single).any()
    solution = solved(single)
    pairs, beyond = jumps_beyond(single, solution)
    second = two_point_split(single, solution, 0, apart=pairs[beyond])
    truth = points[keep][single.landmark_index == 0] == 8
    assert max(np.mean(second == truth), np.mean(second != truth)) >= 0.95
    with pytest.raises(ValueError, match="cannot be one point"):
        two_point_split(single, solution, 0)
    with pytest.raises(ValueError, match="ρ"):
        sighting_jumps(single, solution, np.full(len(single.ranges), 0.02), 0.005, 0.0, 1.0)


def landmarks_that_jump(problem: LandmarkLogProblem, solution, alpha: float = 0.01) -> np.ndarray:
    """:func:`jumping_landmarks` under :func:`twin_log`'s sensor (0.02 m, 0.005 rad, no correlation)."""
    return jumping_landmarks(problem, solution, np.full(len(problem.ranges), 0.02), 0.005, 0.0, 0.0, alpha, gap_s=1.0)


# The twin beside landmark 0 as the robot sees it: between −1.4 and −1.1 rad the smoother keeps both points at every
# separation (measured: 6 of 6 draws at each of 0.5, 0.8, 1.1 and 1.5 m), so there are kept switches to jump. One
# behind the other (0 or ±π), the ranges' 0.5–1.5 m is 10–30 σ of the model's and it drops one point's sightings:
# over all directions 360 of 1500 draws kept switches, and the derandomized draws of −π..π filtered 50 of 51.
@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2 ** 16), separation=st.floats(0.5, 1.5), direction=st.floats(-1.4, -1.1))
@example(seed=1794, separation=0.5, direction=2.0)      # landmark 2 jumps 30.4 > 20.9 at α 0.01 in both maps (RARE)
def test_the_name_of_two_points_is_the_one_whose_kept_sightings_jump(seed, separation, direction):
    problem, points = twin_log(seed, separation, direction)
    solution = solved(problem)
    mine = np.flatnonzero((problem.landmark_index == 0) & solution.inliers)
    mine = mine[np.argsort(problem.pose_index[mine], kind="stable")]
    step = np.diff(problem.pose_index[mine])
    switches = int(np.sum((step == 1) & (points[mine][1:] != points[mine][:-1])))
    assume(switches > 0)        # both points kept in consecutive frames (else the smoother kept one a stretch)
    assert landmarks_that_jump(problem, solution)[0] >= 0.9 * switches   # measured: every kept switch, 2 draws of 6
    assert not landmarks_that_jump(problem, solution, RARE)[1:].any()     # α 0.01: 1 draw in ~750 fails (RARE)
    honest, _ = twin_log(seed, separation, direction, one_name=False)
    assert not landmarks_that_jump(honest, solved(honest), RARE).any()


def test_an_honest_map_jumps_no_more_often_than_alpha():
    """The false-alarm rate the hypothesis tests cannot assert draw by draw (RARE), on fixed seeds: the jumps between
    an honest map's consecutive kept sightings are no more often beyond χ²₂'s quantiles than χ²₂ (the Bonferroni bound
    over a map's pairs rests on it), and the maps flagged at α 0.01 are as few as a rate ≤ α allows."""
    jumps, flagged = [], 0
    for seed in range(40):
        honest, _ = twin_log(seed, 0.5 + (seed % 5) / 4, float(seed), one_name=False)
        solution = solved(honest)
        jumps.append(sighting_jumps(honest, solution, np.full(len(honest.ranges), 0.02), 0.005, 0.0, 0.0, gap_s=1.0,
                                    among=solution.inliers)[1])
        flagged += landmarks_that_jump(honest, solution).any()
    jump = np.concatenate(jumps)
    for p in (0.1, 0.01, 0.001):            # measured over 4000 maps' 1.3 M pairs: 0.047, 0.0023, 1.2e-4
        assert np.mean(jump > chi2.isf(p, 2)) <= p
    assert flagged <= 3                     # P(Bin(40, 0.01) > 3) < 0.001; measured 2 maps of 4000 (0.05 %)


def test_a_sighting_the_smoother_leaves_out_makes_no_landmark_jump():
    problem, points = twin_log(3, 0.8, 1.0, one_name=False)
    stray = np.flatnonzero(points == 1)[len(np.flatnonzero(points == 1)) // 2]     # mid-way through a landmark's
    ranges = problem.ranges.copy()
    ranges[stray] += 1.0                             # 20 σ of the model's range: a reading of something 1 m beyond
    problem = dataclasses.replace(problem, ranges=ranges)
    solution = solved(problem)
    assert not solution.inliers[stray]
    pairs, beyond = jumps_beyond(problem, solution)
    assert beyond[(pairs == stray).any(axis=1)].any()    # the jump test sees the stray's steps
    assert not landmarks_that_jump(problem, solution).any()
    with pytest.raises(ValueError, match="α"):
        jumping_landmarks(problem, solution, np.full(len(problem.ranges), 0.02), 0.005, 0.0, 0.0, 1.0)


def test_a_step_in_range_alone_makes_a_landmark_jump_in_both_components_but_not_in_bearing_alone():
    problem, points = twin_log(5, 0.8, 1.0, one_name=False)
    mine = np.flatnonzero(points == 1)
    steps = np.flatnonzero(np.diff(problem.pose_index[mine]) == 1) + 1        # sightings one frame after another
    later = mine[steps[len(steps) // 2]:]
    ranges = problem.ranges.copy()
    ranges[later] += 0.25        # the rest read 25 cm long, as MRCLAM robot 5's range steps (0.28–0.37 m at 8 m)
    problem = dataclasses.replace(problem, ranges=ranges)
    solution = solved(problem)
    assert solution.inliers[mine].all()             # within the model's σ (0.05 m): the smoother keeps every one
    both = landmarks_that_jump(problem, solution)
    bearing = jumping_landmarks(problem, solution, np.full(len(problem.ranges), 0.02), 0.005, 0.0, 0.0, 0.01,
                                gap_s=1.0, bearing_only=True)
    assert both[1] >= 1 and not np.delete(both, 1).any()
    assert not bearing.any()
