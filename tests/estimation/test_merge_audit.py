"""Parts of a merged name tested against the rest of it (estimation/merge_audit.py), on simulated logs whose names
before the merge are one per landmark and lap: a right merge joins one landmark's laps, a wrong one a lap of another
landmark."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation import chi2
from estimation.geometry import between, dead_reckoning, wrap_angle
from estimation.landmark_smoother import LandmarkLogProblem, landmarks_from_first_sightings, smooth
from estimation.merge_audit import covisible_spacing, floored_scores, held_parts, merged_parts, part_splits

SIGMA_R, SIGMA_B = 0.05, 0.02
STEPS, LAP, MARKS = 240, 120, 8         # 1 s a step, a 2 m circle in 120 steps (2 laps), 8 landmarks around it
LOOSE = (200, 222)                       # steps of the second lap seen only through the wrong part (loose case)


def circle_log(seed: int, wrong: tuple[int, np.ndarray] | None = None, loose: bool = False):
    """A robot driving a 2 m circle among 8 landmarks 3.2 m from its centre; odometry and sightings drawn from the
    model. Names before the merge: one per landmark and lap (landmark + 8·lap); after it, the landmark's. ``wrong``
    (a, offset): on the second lap the robot sees, instead of landmark a, another point ``offset`` (2,) from it,
    under a name of its own before the merge and a's after it (a wrong part of a's name, as MRCLAM's posts 19 and
    20, 0.73 m apart). ``loose``: over the steps LOOSE the odometry is loose (σ 0.5 m and rad over the stretch),
    the other point is seen there only, and nothing else is. Returns the problem, each sighting's name before the
    merge, whether it is of the wrong point, and the landmarks' true positions."""
    rng = np.random.default_rng(seed)
    step = np.array([2 * np.pi * 2.0 / LAP, 0.0, 2 * np.pi / LAP])
    truth = dead_reckoning(np.tile(step, (STEPS, 1)))
    angles = np.linspace(0, 2 * np.pi, MARKS, endpoint=False)
    landmarks = np.column_stack([3.2 * np.cos(angles), 2.0 + 3.2 * np.sin(angles)])
    variance = np.tile(2e-3 * np.hypot(step[0], step[1]), (STEPS, 3))
    if loose:
        variance[LOOSE[0] - 1:LOOSE[1]] = 0.5 ** 2 / (LOOSE[1] - LOOSE[0] + 1)
    measured = between(truth[:-1], truth[1:]) + rng.standard_normal((STEPS, 3)) * np.sqrt(variance)
    pose_index, seen, before, after, ranges, bearings = [], [], [], [], [], []
    for k in range(1, STEPS + 1):
        lap = min(k // LAP, 1)
        in_loose = LOOSE[0] <= k < LOOSE[1]
        for m in range(MARKS):
            wrong_here = wrong is not None and lap == 1 and m == wrong[0] and (in_loose or not loose)
            if loose and in_loose and not wrong_here:
                continue
            d = landmarks[m] + (wrong[1] if wrong_here else 0.0) - truth[k, :2]
            r = np.hypot(d[0], d[1])
            b = wrap_angle(np.arctan2(d[1], d[0]) - truth[k, 2])
            if not (abs(b) < 0.8 and r < 5.0):
                continue
            pose_index.append(k)
            seen.append(wrong_here)
            before.append(m + MARKS * (2 if wrong_here else lap))      # the wrong point's: a name of their own
            after.append(m)
            ranges.append(r + SIGMA_R * rng.standard_normal())
            bearings.append(b + SIGMA_B * rng.standard_normal())
    s = len(ranges)
    problem = LandmarkLogProblem(measured, variance, np.array(pose_index), np.array(after), np.array(ranges),
                                 np.array(bearings), np.full(s, SIGMA_R), np.full(s, SIGMA_B),
                                 increment_seconds=np.ones(STEPS))
    return problem, np.array(before), np.array(seen), landmarks


def solved(problem: LandmarkLogProblem):
    poses = dead_reckoning(problem.increments)
    return smooth(problem, poses, landmarks_from_first_sightings(problem, poses))


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 2 ** 16))
def test_a_part_s_score_is_its_offset_s_chi2_under_the_offset_s_covariance(seed):
    # (part_splits reads map_honesty.split_scores' own δ̂ and V⁻¹: the score must be their quadratic form)
    problem, before, _, _ = circle_log(seed)
    solution = solved(problem)
    parts = merged_parts(problem, solution, before)
    got = part_splits(problem, solution, parts)
    ok = np.isfinite(got.score)
    assert ok.all()
    quadratic = np.einsum("pi,pij,pj->p", got.offset, np.linalg.inv(got.covariance), got.offset)
    assert np.allclose(quadratic, got.score, rtol=1e-6)


def test_each_merged_landmark_is_cut_by_its_earlier_names_and_only_its_kept_sightings_count():
    problem, before, _, _ = circle_log(3)
    solution = solved(problem)
    before = before.copy()
    before[problem.landmark_index == 5] = 5          # landmark 5 carried one name before: nothing merged
    before[:4] = -1                                  # sightings that had no name before
    parts = merged_parts(problem, solution, before)
    kept = np.asarray(solution.inliers, bool)
    covered = np.concatenate([p.sightings for p in parts])
    assert len(np.unique(covered)) == len(covered)
    assert set(covered) == set(np.flatnonzero(kept & (before >= 0) & (problem.landmark_index != 5)))
    for p in parts:
        assert len(set(before[p.sightings])) == 1
        assert np.all(problem.landmark_index[p.sightings] == p.landmark)
    assert {p.landmark for p in parts} == set(range(MARKS)) - {5}
    with pytest.raises(ValueError):
        merged_parts(problem, solution, before[:-1])


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2 ** 16), a=st.integers(0, MARKS - 1), direction=st.floats(-np.pi, np.pi))
def test_a_wrong_part_sits_off_its_name_towards_its_own_point_and_is_refused_first(seed, a, direction):
    true_offset = 0.3 * np.array([np.cos(direction), np.sin(direction)])   # the map frame is the truth's start's
    problem, before, seen, _ = circle_log(seed, wrong=(a, true_offset))
    solution = solved(problem)
    parts = merged_parts(problem, solution, before)
    got = part_splits(problem, solution, parts)
    is_wrong = np.array([seen[p.sightings].all() for p in parts])
    assert is_wrong.sum() == 1
    i = int(np.flatnonzero(is_wrong)[0])
    assert np.linalg.norm(got.offset[i] - true_offset) < 0.4 * np.linalg.norm(true_offset)   # first order: bent map
    assert got.score[i] > chi2.isf(0.01 / len(parts), 2)
    others = np.array([p.landmark != parts[i].landmark for p in parts])    # a name of two parts: one score for both
    assert got.score[i] > np.nanmax(got.score[others])
    held = held_parts(got, floor_m=0.042, spacing_m=covisible_spacing(problem, solution))
    assert held["refused"][i] and not held["untestable"].any()
    floored = floored_scores(got, 0.042)        # the neighbours it bends may be refused too, never above it
    assert floored[i] > np.nanmax(floored[others])


def test_right_parts_score_as_chi2_with_two_degrees_of_freedom():
    scores = []
    for seed in range(4):
        problem, before, _, _ = circle_log(seed)
        solution = solved(problem)
        scores.append(part_splits(problem, solution, merged_parts(problem, solution, before)).score)
    scores = np.concatenate(scores)
    assert len(scores) >= 40
    assert np.mean(scores > chi2.ppf(0.95, 2)) <= 0.15
    assert 0.5 < np.median(scores) / chi2.ppf(0.5, 2) < 2.0


def test_a_part_seen_only_from_a_loose_stretch_has_a_wide_offset_and_is_untestable():
    widest_wrong, widest_right = [], []
    for seed in range(3):
        problem, before, seen, _ = circle_log(seed, wrong=(5, np.array([0.0, 0.7])), loose=True)
        solution = solved(problem)
        parts = merged_parts(problem, solution, before)
        got = part_splits(problem, solution, parts)
        widest = got.widest_sigma()
        is_wrong = np.array([seen[p.sightings].all() for p in parts])
        widest_wrong.append(widest[is_wrong][0])
        widest_right.append(np.nanmax(widest[~is_wrong]))
        held = held_parts(got, floor_m=0.042, spacing_m=0.7)        # as if a neighbour post stood 0.7 m away
        assert held["untestable"][is_wrong][0]
        assert not held["refused"][~is_wrong].any()
    assert min(widest_wrong) > 3 * max(widest_right)


def test_the_spacing_is_the_nearest_two_landmarks_seen_in_one_frame_and_the_floor_only_lowers_scores():
    problem, before, _, landmarks = circle_log(5)
    solution = solved(problem)
    chord = 2 * 3.2 * np.sin(np.pi / MARKS)                  # neighbours on the circle; only they share frames
    assert covisible_spacing(problem, solution) == pytest.approx(chord, abs=0.1)
    got = part_splits(problem, solution, merged_parts(problem, solution, before))
    assert np.allclose(floored_scores(got, 0.0), got.score, rtol=1e-9)
    assert np.all(floored_scores(got, 0.05) < got.score)
    with pytest.raises(ValueError):
        held_parts(got, floor_m=0.04, spacing_m=0.0)
