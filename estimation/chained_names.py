"""Names for a log's sightings without barcodes: the unknown-association filter over overlapping windows, chained.

The identities of a landmark log are unknown (MRCLAM without its barcodes); this module names each sighting with no
help from them:

1. **Windows** (:func:`overlapping_windows`, :func:`run_windows`): windows of ``seconds`` starting every ``step``
   (default: half a window, so every sighting lies in two), each run through the unknown-association filter from its
   own start (``run_landmark_log(association="unknown")``); each sighting is named by the window map's landmark it
   falls on (:func:`name_sightings`: the best particle's pose, nearest within χ²₂ 99 %, one sighting per landmark a
   frame).
2. **Chained** (:func:`chain_windows`): landmark a of window k and b of window k + 1 are one name when a clear
   majority (> ½) of a's sightings in the overlap are b's in window k + 1 and of b's are a's (mutual). A landmark with
   no such partner starts a new name. Each sighting takes the name of its core window (the one whose middle is
   nearest its time; the other window's if the core one left it unnamed).

:func:`chain_log` does both. The names feed :mod:`estimation.named_smoothing` (a smoothing problem per naming).

Measured in ``benchmarks/mrclam_chained_names.py`` (its docstring; docs/fastslam-history.md, "Session 21: names
chained through overlapping windows ... (U)"): robots 1-5 of MRCLAM data set 2, seed 0, 40 s windows every 20 s,
the calibrated noise model: 0.08-1.22 % of the sightings under a name of another barcode, but a post re-seen after
more than the overlap is a new name (8-16 names per post), which the loop-closing of that benchmark and of
``benchmarks/mrclam_constellation.py`` (sessions 23 and 25 of the same notebook) then merge. Moved here from the
benchmark in session 36 (A), unchanged (the same names and smoothed solution, bit for bit, on robots 2 and 5).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.geometry import compose
from estimation.landmark_map import LandmarkMap
from estimation.noise_model import NoiseModel

CHI2_2_99 = 9.210                 # χ²₂ 99 %: a sighting falls on a landmark
MIN_WINDOW_FRAMES = 2             # a window with fewer sighting frames makes no map
WINDOW_S = 40.0                   # the measured window (session 21); windows start every half of it by default


@dataclass
class Window:
    """One window: its span [start_time, start_time + seconds) of log time, its sightings (N,) (indices into the log)
    and their times, the row of ``map`` each falls on (−1: none within the gate), the filter's map of the window (in
    the robot's frame at the window's first sighting)."""

    start_time: float
    seconds: float
    sightings: np.ndarray
    times: np.ndarray
    sighting_landmark: np.ndarray
    map: LandmarkMap


@dataclass
class ChainedNames:
    """names (N,) per sighting of the log (−1: unnamed); window_names[w] (n_w,) the name of each landmark of window
    w; links: chain links made between consecutive windows; unlinked: landmarks with overlap sightings but no mutual
    partner (a new name starts there); windows: the windows chained (empty when the names came from elsewhere, e.g.
    a cache)."""

    names: np.ndarray
    window_names: list[np.ndarray]
    links: int = 0
    unlinked: int = 0
    windows: list[Window] = field(default_factory=list)


def chain_log(log: RangeBearingLog, noise: NoiseModel, config: FastSLAMConfig, *, seconds: float = WINDOW_S,
              step: float | None = None, seed: int = 0, min_shared: int = 1) -> ChainedNames:
    """The chained names of ``log`` (module docstring, steps 1 and 2): :func:`run_windows` of ``seconds`` every
    ``step`` s (None: ``seconds`` / 2) with the filter ``config`` (its particle count) and ``noise``, window k's
    filter seeded ``[seed, k]``; then :func:`chain_windows`."""
    windows = run_windows(log, seconds, config, noise, seed=seed, step=step)
    return chain_windows(windows, len(log), min_shared=min_shared)


def overlapping_windows(log: RangeBearingLog, seconds: float, step: float | None = None
                        ) -> list[tuple[float, np.ndarray, RangeBearingLog]]:
    """Windows of ``seconds`` starting every ``step`` (default seconds / 2) from the first sighting: (start time, the
    log's sighting indices, the window's log). A window's log holds its sightings and the odometry and ground truth
    around them (one row either side); windows with fewer than MIN_WINDOW_FRAMES sighting frames are left out."""
    if not seconds > 0:
        raise ValueError(f"a window lasts > 0 s, not {seconds}")
    step = seconds / 2 if step is None else float(step)
    if not 0 < step <= seconds:
        raise ValueError(f"windows start every 0 < step <= {seconds} s, not {step}")
    if len(log) == 0:
        return []
    t_first, t_last = float(log.sighting_times[0]), float(log.sighting_times[-1])
    out = []
    start = t_first
    while start <= t_last:
        rows = np.flatnonzero((log.sighting_times >= start) & (log.sighting_times < start + seconds))
        if len(np.unique(log.sighting_times[rows])) >= MIN_WINDOW_FRAMES:
            times = log.sighting_times[rows]
            out.append((start, rows, _sub_log(log, rows, float(times[0]), float(times[-1]))))
        if start + seconds > t_last:
            break
        start += step
    return out


def _sub_log(log: RangeBearingLog, rows: np.ndarray, t0: float, t1: float) -> RangeBearingLog:
    def around(table: np.ndarray) -> np.ndarray:
        if len(table) == 0:
            return table
        a = max(int(np.searchsorted(table[:, 0], t0, side="right")) - 1, 0)
        b = min(int(np.searchsorted(table[:, 0], t1, side="left")) + 1, len(table) - 1)
        return table[a:b + 1]

    return dataclasses.replace(log, odometry=around(log.odometry), sighting_times=log.sighting_times[rows],
                               ranges=log.ranges[rows], bearings=log.bearings[rows],
                               landmark_ids=log.landmark_ids[rows], ground_truth=around(log.ground_truth))


def run_windows(log: RangeBearingLog, seconds: float, config: FastSLAMConfig, noise: NoiseModel, *, seed: int = 0,
                step: float | None = None) -> list[Window]:
    """Every window of :func:`overlapping_windows` through the unknown-association filter from its own start, its
    sightings named by its map. The sightings are placed from the map's own trajectory (the best particle's, in the
    window's frame: the robot's pose at the window's first sighting), so a log without ground truth is named as one
    with it: the truth only scores the run."""
    sensor = noise.range_bearing
    inflate_r, inflate_b = (float(np.sqrt(f)) for f in sensor.variance_inflation())
    out = []
    for k, (start, rows, sub) in enumerate(overlapping_windows(log, seconds, step)):
        run = run_landmark_log(sub, config, np.random.default_rng([seed, k]), noise=noise, association="unknown",
                               robot=f"{log.name}@{start:.0f}s")
        frame_times, poses = run.map.trajectory[1:, 0], run.map.trajectory[1:, 1:]   # row 0: the initial pose
        ranges, bearings = sensor.corrected(sub.ranges, sub.bearings)
        sigma_r = sensor.range_sigma(ranges) * inflate_r
        sigma_b = np.full(len(ranges), sensor.bearing_sigma_rad * inflate_b)
        frame = np.searchsorted(frame_times, sub.sighting_times)
        labels = name_sightings(run.map, poses[frame], frame, ranges, bearings, sigma_r, sigma_b)
        out.append(Window(start, seconds, rows, sub.sighting_times, labels, run.map))
    return out


def name_sightings(landmarks: LandmarkMap, poses: np.ndarray, frame: np.ndarray, ranges: np.ndarray,
                   bearings: np.ndarray, sigma_r: np.ndarray, sigma_b: np.ndarray) -> np.ndarray:
    """(N,) the row of ``landmarks`` each sighting falls on, −1 for none.

    poses (N, 3): the pose each sighting was taken from, in the map's frame; frame (N,): its frame (one landmark per
    frame); ranges, bearings, sigma_r, sigma_b (N,). d² of the placed sighting to each landmark under the landmark's
    covariance (x, y) plus the sighting's; the nearest within χ²₂ 99 %, assigned greedily by d² within a frame."""
    n = len(ranges)
    out = np.full(n, -1, np.int64)
    if n == 0 or len(landmarks) == 0:
        return out
    heading = poses[:, 2] + bearings
    points = compose(poses, np.column_stack([ranges * np.cos(bearings), ranges * np.sin(bearings),
                                             np.zeros(n)]))[:, :2]
    u = np.column_stack([np.cos(heading), np.sin(heading)])
    v = np.column_stack([-np.sin(heading), np.cos(heading)])
    R = (sigma_r ** 2)[:, None, None] * u[:, :, None] * u[:, None, :] \
        + ((ranges * sigma_b) ** 2)[:, None, None] * v[:, :, None] * v[:, None, :]
    diff = points[:, None, :] - landmarks.positions[None, :, :2]
    S = R[:, None] + landmarks.covariances[None, :, :2, :2]
    d2 = np.einsum("nli,nli->nl", diff, np.linalg.solve(S, diff[..., None])[..., 0])
    for f in np.unique(frame):
        rows = np.flatnonzero(frame == f)
        block = d2[rows].copy()
        while True:
            r, c = np.unravel_index(np.argmin(block), block.shape)
            if not block[r, c] < CHI2_2_99:
                break
            out[rows[r]] = c
            block[r, :] = np.inf
            block[:, c] = np.inf
    return out


def chain_windows(windows: list[Window], n_sightings: int, *, min_shared: int = 1) -> ChainedNames:
    """Names across the log from consecutive windows' shared sightings (module docstring, step 2). ``min_shared``:
    the fewest overlap sightings two landmarks must share to be linked."""
    window_names: list[np.ndarray] = []
    next_name = 0
    links = unlinked = 0
    for k, w in enumerate(windows):
        names = np.full(len(w.map), -1, np.int64)
        if k > 0:
            partner = _mutual_partners(windows[k - 1], w, min_shared)
            for b, a in partner.items():
                names[b] = window_names[k - 1][a]
            links += len(partner)
            unlinked += len(_overlap_landmarks(windows[k - 1], w)) - len(partner)
        for b in np.flatnonzero(names < 0):
            names[b] = next_name
            next_name += 1
        window_names.append(names)
    out = np.full(n_sightings, -1, np.int64)
    distance = np.full(n_sightings, np.inf)
    for w, names in zip(windows, window_names, strict=True):
        named = w.sighting_landmark >= 0
        rows = w.sightings[named]
        middle = w.start_time + w.seconds / 2
        # the core window (nearest middle) names a sighting; another window only one the core window left unnamed
        d = np.abs(w.times[named] - middle)
        better = (d < distance[rows]) | (out[rows] < 0)
        out[rows[better]] = names[w.sighting_landmark[named][better]]
        distance[rows[better]] = d[better]
    return ChainedNames(out, window_names, links, unlinked, list(windows))


def _overlap_landmarks(a: Window, b: Window) -> set[int]:
    """Landmarks of ``b`` named by sightings ``a`` also holds."""
    shared = np.isin(b.sightings, a.sightings)
    labels = b.sighting_landmark[shared]
    return set(int(x) for x in labels[labels >= 0])


def _mutual_partners(a: Window, b: Window, min_shared: int) -> dict[int, int]:
    """{landmark of b: landmark of a} for pairs sharing a clear majority (> ½) of each one's overlap sightings."""
    common, ia, ib = np.intersect1d(a.sightings, b.sightings, return_indices=True)
    la, lb = a.sighting_landmark[ia], b.sighting_landmark[ib]
    out = {}
    for x in np.unique(la[la >= 0]):
        of_x = la == x
        ys, counts = np.unique(lb[of_x & (lb >= 0)], return_counts=True)
        if not len(ys):
            continue
        y, c = int(ys[np.argmax(counts)]), int(counts.max())
        if c < min_shared or 2 * c <= int(of_x.sum()) or 2 * c <= int((lb == y).sum()):
            continue
        out[y] = int(x)
    return out
