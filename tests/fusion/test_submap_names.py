"""Names from submaps (fusion/submap_names.py): short windows named by the unknown-association filter, joined by the
fusion's alignment; on synthetic logs of posts with a drifting odometry, where the truth is known."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.datasets import RangeBearingLog
from estimation.fastslam import range_bearing_config
from estimation.geometry import wrap_angle
from estimation.landmark_map import LandmarkMap
from estimation.noise_model import estimate_noise
from fusion.alignment import Alignment
from fusion.submap_names import join_window_maps, name_sightings, run_windows, sighting_names, split_log


def _random_posts(rng, n=45, half=8.0, spacing=1.2) -> np.ndarray:
    out: list[np.ndarray] = []
    while len(out) < n:
        p = rng.uniform(-half, half, 2)
        if all(np.hypot(*(p - q)) >= spacing for q in out):
            out.append(p)
    return np.array(out)


def _lattice(period=2.0, half=8.0) -> np.ndarray:
    g = np.arange(-half, half + 1e-9, period)
    return np.array([(x, y) for x in g for y in g])


def _drive(rng, posts, seconds=220.0, radius=5.0, speed=0.3, sensor_range=5.0) -> RangeBearingLog:
    """Two laps of a circle among ``posts`` (0.3 m/s), sightings of every post within 5 m every 0.5 s (σ 2 cm,
    0.01 rad); the odometry 2 % long with a random walk (σ 0.01 m/√m, 0.01 rad/√m): 2 m of drift in a lap."""
    dt = 0.02
    t = np.arange(0.0, seconds + dt / 2, dt)
    w = speed / radius
    truth = np.column_stack([radius * np.cos(w * t), radius * np.sin(w * t), wrap_angle(np.pi / 2 + w * t)])
    steps = np.tile([speed * dt, 0.0, w * dt], (len(t) - 1, 1))
    noisy = steps * [1.02, 1.0, 1.0] + rng.standard_normal(steps.shape) * 0.01 * np.sqrt(speed * dt)
    heading = truth[0, 2] + np.concatenate([[0.0], np.cumsum(noisy[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    xy = truth[0, :2] + np.vstack([[0.0, 0.0], np.cumsum(np.column_stack([c * noisy[:, 0] - s * noisy[:, 1],
                                                                          s * noisy[:, 0] + c * noisy[:, 1]]), 0)])
    rows = []
    for k in range(0, len(t), 25):
        delta = posts - truth[k, :2]
        r = np.hypot(delta[:, 0], delta[:, 1])
        for i in np.flatnonzero((r < sensor_range) & (r > 0.3)):
            b = np.arctan2(delta[i, 1], delta[i, 0]) - truth[k, 2]
            rows.append((t[k], r[i] + 0.02 * rng.standard_normal(), wrap_angle(b + 0.01 * rng.standard_normal()), i))
    rows = np.array(rows)
    ids = np.arange(len(posts)) + 100
    return RangeBearingLog("synthetic-posts", np.column_stack([t, xy, wrap_angle(heading)]), rows[:, 0], rows[:, 1],
                           rows[:, 2], ids[rows[:, 3].astype(int)], np.column_stack([t, truth]), ids, posts)


def _majority(names: np.ndarray, truth: np.ndarray) -> dict[int, int]:
    out = {}
    for name in np.unique(names[names >= 0]):
        values, counts = np.unique(truth[names == name], return_counts=True)
        out[int(name)] = int(values[np.argmax(counts)])
    return out


def _run(posts_seed: int, posts: str):
    rng = np.random.default_rng(posts_seed)
    log = _drive(rng, _random_posts(rng) if posts == "random" else _lattice())
    windows = run_windows(log, 40.0, range_bearing_config(n_particles=30), estimate_noise([log]).model)
    joined = join_window_maps([w.map for w in windows])
    names = sighting_names(windows, joined, len(log))
    post_of = [_majority(w.sighting_landmark, log.landmark_ids[w.sightings]) for w in windows]
    wrong_joins = [(a, b) for a, b in joined.joins if post_of[a[0]].get(a[1]) != post_of[b[0]].get(b[1])]
    return log, windows, joined, names, wrong_joins


def _wrong(names: np.ndarray, truth: np.ndarray) -> int:
    owner = _majority(names, truth)
    return int(sum(owner[int(n)] != int(t) for n, t in zip(names, truth, strict=True) if n >= 0))


def test_a_drifting_log_among_distinct_posts_gets_one_name_per_post():
    log, windows, joined, names, wrong_joins = _run(1, "random")
    # the whole log's odometry drifts by metres, the posts are 1.2 m apart; each 40 s window is named right
    for w in windows:
        assert _wrong(w.sighting_landmark, log.landmark_ids[w.sightings]) == 0
    assert len(joined.found) >= len(windows) - 1 and joined.window_components == 1
    assert wrong_joins == [] and joined.refused == []
    assert _wrong(names, log.landmark_ids) == 0
    # one name per post, beyond the duplicates a window made itself (two landmarks of one window are never joined)
    counts = {int(n): int(np.sum(names == n)) for n in np.unique(names[names >= 0])}
    names_of_posts = {}
    for name, post in _majority(names, log.landmark_ids).items():
        if counts[name] >= 5:
            names_of_posts.setdefault(post, []).append(name)
    window_duplicates = sum(
        len(w.map) - len(set(_majority(w.sighting_landmark, log.landmark_ids[w.sightings]).values()))
        for w in windows)
    assert set(names_of_posts) == set(np.unique(log.landmark_ids).tolist())
    assert sum(len(v) - 1 for v in names_of_posts.values()) <= window_duplicates
    assert np.mean(names >= 0) > 0.98


def test_posts_on_a_lattice_are_never_joined_wrongly():
    log, windows, joined, names, wrong_joins = _run(2, "lattice")
    # every window map repeats itself under a shift of one period: the alignment is ambiguous, not wrong
    assert wrong_joins == []
    assert _wrong(names, log.landmark_ids) == sum(_wrong(w.sighting_landmark, log.landmark_ids[w.sightings])
                                                  for w in windows)


def _points(n: int) -> LandmarkMap:
    xy = np.column_stack([np.arange(n, dtype=float), np.zeros(n)])
    return LandmarkMap(np.column_stack([xy, np.zeros(n)]), np.tile(np.eye(3) * 1e-4, (n, 1, 1)),
                       np.zeros((n, 0), np.float32))


def test_a_chain_of_joins_that_puts_two_landmarks_of_one_window_under_one_name_is_refused():
    maps = [_points(3), _points(3), _points(3)]
    found = {(0, 1): [(0, 0), (1, 1)], (1, 2): [(0, 0), (2, 2)], (0, 2): [(1, 0), (0, 1)]}
    strength = {(0, 1): -9.0, (1, 2): -8.0, (0, 2): -7.0}

    def fake_align(map1, map2, preset, rng, prior):
        i, j = next(k for k in found if maps[k[0]] is map1 and maps[k[1]] is map2)
        result = Alignment.from_pose(np.zeros(3), supports=found[(i, j)])
        stats = result.statistics.__class__(supports=len(found[(i, j)]), log10_chance_probability=strength[(i, j)])
        return Alignment(True, "robust", result.pose, None, result.supports, stats)

    joined = join_window_maps(maps, align_fn=fake_align)
    # 0-1 and 1-2 join window 0's row 0 with window 2's row 0 through window 1; 0-2 would add window 0's row 1 to it
    assert [(i, j) for i, j, _ in joined.found] == [(0, 1), (1, 2)]
    assert [r.windows for r in joined.refused] == [(0, 2)] and "window 0" in joined.refused[0].why
    assert joined.names[0][0] == joined.names[1][0] == joined.names[2][0]
    assert len({int(joined.names[0][1]), int(joined.names[2][1])}) == 2     # the refused alignment joined nothing
    assert joined.window_components == 1 and joined.tried == 3


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 12))
def test_exact_sightings_are_named_by_their_landmark(seed, n):
    rng = np.random.default_rng(seed)
    landmarks = np.column_stack([np.arange(n) * 1.5, rng.uniform(-0.3, 0.3, n), np.zeros(n)])
    covariances = np.tile(np.diag([0.01, 0.01, 1e-6]), (n, 1, 1))
    lmap = LandmarkMap(landmarks, covariances, np.zeros((n, 0), np.float32))
    which = np.concatenate([rng.permutation(n) for _ in range(3)])   # each frame sees a landmark at most once
    frames = np.repeat(np.arange(3), n)
    poses = np.column_stack([rng.uniform(-3, 3, 3), rng.uniform(-4, -2, 3), rng.uniform(-np.pi, np.pi, 3)])[frames]
    delta = landmarks[which, :2] - poses[:, :2]
    ranges = np.hypot(delta[:, 0], delta[:, 1])
    bearings = wrap_angle(np.arctan2(delta[:, 1], delta[:, 0]) - poses[:, 2])
    got = name_sightings(lmap, poses, frames, ranges, bearings, np.full(len(which), 0.02), np.full(len(which), 0.01))
    assert np.array_equal(got, which)
    # a landmark the map does not hold is not forced onto another one 1.5 m away
    kept = LandmarkMap(landmarks[1:], covariances[1:], np.zeros((n - 1, 0), np.float32))
    got = name_sightings(kept, poses, frames, ranges, bearings, np.full(len(which), 0.02), np.full(len(which), 0.01))
    assert np.array_equal(got, np.where(which == 0, -1, which - 1))


def test_windows_split_the_sightings_once_each():
    rng = np.random.default_rng(3)
    log = _drive(rng, _random_posts(rng), seconds=60.0)
    parts = split_log(log, 17.0)
    rows = np.concatenate([p[1] for p in parts])
    assert len(np.unique(rows)) == len(rows) <= len(log)
    for start, r, sub in parts:
        assert np.all((log.sighting_times[r] >= start) & (log.sighting_times[r] < start + 17.0))
        assert sub.odometry[0, 0] <= sub.sighting_times[0] and sub.odometry[-1, 0] >= sub.sighting_times[-1]
