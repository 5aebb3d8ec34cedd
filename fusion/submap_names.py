"""Names for a range-bearing log's sightings without identities: short submaps, joined by the fusion's alignment.

Association by position alone fails over a whole log when the odometry's drift grows as wide as the landmarks'
spacing (MRCLAM: posts 0.7–1.9 m apart, drift of metres; docs/fastslam.md "Session 10: unknown association"). Over
a short stretch the drift is small, so the unknown-association filter run from the stretch's start names its
sightings (nearly) right; what is left is to tell which landmark of one stretch is which of another, and that is
what :func:`fusion.align` does for two robots' maps, with a "found" built never to report a wrong alignment.

- :func:`split_log` cuts a log into windows of T seconds from its first sighting.
- :func:`run_windows` runs the unknown-association filter (``estimation.dataset_slam.run_landmark_log``) on each
  window from the window's own start, and names each sighting by the window map's landmark it falls on: the
  sighting placed from the best particle's pose at its frame, the nearest landmark by d² under the landmark's and the
  sighting's covariance within χ²₂ 99 %, one sighting per landmark in a frame (a frame never sees a post twice).
- :func:`join_window_maps` aligns the window maps pairwise (robust preset, no descriptors: geometry alone); a found
  alignment's supports are correspondences, joined transitively by union-find. A name may hold at most one landmark
  of a window (one window's landmarks are distinct posts by its own association), so every join is checked against
  the sets as they stand: an alignment any of whose supports would put two landmarks of one window under one name,
  directly or through a chain of earlier joins, contradicts what is already joined and is refused **whole** (its
  other supports are not trusted either). Alignments are applied strongest first (lowest false-alarm probability),
  so a contradiction refuses the weaker side.
  :func:`odometry_prior` gives each pair a start prior from the calibrated odometry between the windows' frames.
- :func:`sighting_names` gives every sighting of the log its joined name (−1: unnamed); :func:`with_names` the log
  with the names as identities (for the known-ID filter and smoother).

Measured on MRCLAM (docs/fastslam.md, "Session 17: names from submaps (V)"): the windows are nearly right, but maps of
a few of 15 posts without descriptors do not carry the evidence to be aligned, so the names stay unjoined; on the
synthetic logs of the tests (20–30 landmarks a window) the names are the posts'.

The barcodes a data set carries never enter here: they only score the names (``benchmarks.mrclam_submap_association``).
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.geometry import between, compose
from estimation.landmark_map import LandmarkMap
from estimation.noise_model import NoiseModel

from .alignment import Alignment, align
from .alignment_config import AlignmentConfig
from .prior import StartPrior

CHI2_2_99 = 9.210                 # χ²₂ 99 %: a sighting falls on a landmark
MIN_WINDOW_FRAMES = 2             # a window with fewer sighting frames makes no map


@dataclass
class Window:
    """One window's map and the names it gives its sightings.

    start_time, seconds: the window's span in log time; sightings (N,) indices into the log's sightings;
    sighting_landmark (N,) the row of ``map`` each one falls on (−1: none within the gate); map: the filter's map of
    the window, in the robot's frame at the window's first sighting (log time ``first_time``); odometry_start (3,)
    that frame's pose in the odometry's (dead-reckoned) frame."""

    start_time: float
    seconds: float
    sightings: np.ndarray
    sighting_landmark: np.ndarray
    map: LandmarkMap
    odometry_start: np.ndarray
    first_time: float


@dataclass(frozen=True)
class Refusal:
    """A found alignment not applied: the two windows, its supports and why."""

    windows: tuple[int, int]
    supports: int
    why: str


@dataclass
class JoinedNames:
    """names[w] (n_w,): the name of each landmark of window w (every landmark has one; a landmark joined to none keeps
    a name of its own). found: the found alignments (i, j, Alignment) applied; refused: those found but refused;
    joins: the support pairs ((i, row), (j, row)) applied; tried: alignments computed; window_links[w]: alignments
    applied that touch window w; window_components: connected components of the windows under the applied
    alignments."""

    names: list[np.ndarray]
    tried: int = 0
    found: list[tuple[int, int, Alignment]] = field(default_factory=list)
    refused: list[Refusal] = field(default_factory=list)
    joins: list[tuple[tuple[int, int], tuple[int, int]]] = field(default_factory=list)
    window_links: list[int] = field(default_factory=list)
    window_components: int = 0


def split_log(log: RangeBearingLog, seconds: float) -> list[tuple[float, np.ndarray, RangeBearingLog]]:
    """Windows of ``seconds`` from the first sighting: (start time, the log's sighting indices, the window's log).
    A window's log holds its sightings, the odometry and ground truth around them (one row either side, so the
    window's first frame interpolates); windows with fewer than MIN_WINDOW_FRAMES sighting frames are left out."""
    if seconds <= 0:
        raise ValueError(f"a window lasts > 0 s, not {seconds}")
    if len(log) == 0:
        return []
    t_first = float(log.sighting_times[0])
    which = np.floor((log.sighting_times - t_first) / seconds).astype(np.int64)
    out = []
    for k in np.unique(which):
        rows = np.flatnonzero(which == k)
        times = log.sighting_times[rows]
        if len(np.unique(times)) < MIN_WINDOW_FRAMES:
            continue
        out.append((t_first + k * seconds, rows, _sub_log(log, rows, float(times[0]), float(times[-1]))))
    return out


def _sub_log(log: RangeBearingLog, rows: np.ndarray, t0: float, t1: float) -> RangeBearingLog:
    def around(table: np.ndarray) -> np.ndarray:
        if len(table) == 0:
            return table
        a = max(int(np.searchsorted(table[:, 0], t0, side="right")) - 1, 0)
        b = min(int(np.searchsorted(table[:, 0], t1, side="left")) + 1, len(table) - 1)
        return table[a:b + 1]

    return RangeBearingLog(log.name, around(log.odometry), log.sighting_times[rows], log.ranges[rows],
                           log.bearings[rows], log.landmark_ids[rows], around(log.ground_truth), log.truth_ids,
                           log.truth_positions, log.notes)


def run_windows(log: RangeBearingLog, seconds: float, config: FastSLAMConfig, noise: NoiseModel, *,
                seed: int = 0) -> list[Window]:
    """Every window of :func:`split_log` through the unknown-association filter from its own start, its sightings
    named by its map (module docstring). ``run_landmark_log`` needs the log's ground truth (it scores every run);
    the names do not use it."""
    sensor = noise.range_bearing
    inflate_r, inflate_b = (float(np.sqrt(f)) for f in sensor.variance_inflation())
    out = []
    for k, (start, rows, sub) in enumerate(split_log(log, seconds)):
        run = run_landmark_log(sub, config, np.random.default_rng([seed, k]), noise=noise, association="unknown",
                               robot=f"{log.name}@{start:.0f}s")
        true_start = np.asarray(run.metrics["true_start_pose"], float)
        poses = between(true_start, run.estimated_trajectory[:, 1:])         # the window's frame
        frame_times = run.estimated_trajectory[:, 0]
        ranges, bearings = sensor.corrected(sub.ranges, sub.bearings)
        sigma_r = sensor.range_sigma(ranges) * inflate_r
        sigma_b = np.full(len(ranges), sensor.bearing_sigma_rad * inflate_b)
        frame = np.searchsorted(frame_times, sub.sighting_times)
        labels = name_sightings(run.map, poses[frame], frame, ranges, bearings, sigma_r, sigma_b)
        t0 = float(sub.sighting_times[0])
        out.append(Window(start, seconds, rows, labels, run.map, log.odometry_pose([t0])[0], t0))
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
    # the sighting's covariance in the map frame: range along the line of sight, bearing across it
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


class _Sets:
    """Union-find over (window, row) landmarks whose every set remembers which row of each window it holds."""

    def __init__(self) -> None:
        self.parent: dict[tuple[int, int], tuple[int, int]] = {}
        self.members: dict[tuple[int, int], dict[int, int]] = {}

    def root(self, node: tuple[int, int]) -> tuple[int, int]:
        if node not in self.parent:
            self.parent[node] = node
            self.members[node] = {node[0]: node[1]}
        while self.parent[node] != node:
            self.parent[node] = self.parent[self.parent[node]]
            node = self.parent[node]
        return node

    def conflict(self, a: tuple[int, int], b: tuple[int, int]) -> str:
        """Why joining a and b would put two landmarks of one window under one name ('' if it would not)."""
        ra, rb = self.root(a), self.root(b)
        if ra == rb:
            return ""
        shared = set(self.members[ra]) & set(self.members[rb])
        if shared:
            w = min(shared)
            return (f"landmark {a} joins landmark {b}, whose names already hold rows {self.members[ra][w]} and "
                    f"{self.members[rb][w]} of window {w}")
        return ""

    def union(self, a: tuple[int, int], b: tuple[int, int]) -> None:
        ra, rb = self.root(a), self.root(b)
        if ra == rb:
            return
        if len(self.members[ra]) < len(self.members[rb]):
            ra, rb = rb, ra
        self.parent[rb] = ra
        self.members[ra].update(self.members.pop(rb))

    def copy(self) -> _Sets:
        other = _Sets()
        other.parent = dict(self.parent)
        other.members = {k: dict(v) for k, v in self.members.items()}
        return other


def join_window_maps(maps: Sequence[LandmarkMap], *, rng: np.random.Generator | None = None,
                     max_gap: int | None = None, preset: str | AlignmentConfig = "robust",
                     priors: Callable[[int, int], StartPrior | None] | None = None, align_fn=align) -> JoinedNames:
    """Join window maps' landmarks under common names (module docstring).

    maps: each window's map in its own frame; ``max_gap``: align only windows at most this many apart (None: every
    pair); ``priors(i, j)``: a start prior on window j's frame in window i's (:class:`fusion.prior.StartPrior`, e.g.
    :func:`odometry_prior`; None: none); ``align_fn(map1, map2, preset=, rng=, prior=)`` the alignment (default
    :func:`fusion.align`)."""
    rng = np.random.default_rng(0) if rng is None else rng
    n = len(maps)
    candidates = []
    tried = 0
    for i in range(n):
        for j in range(i + 1, n if max_gap is None else min(n, i + max_gap + 1)):
            if len(maps[i]) < 2 or len(maps[j]) < 2:
                continue
            tried += 1
            result = align_fn(maps[i], maps[j], preset=preset, rng=rng,
                              prior=None if priors is None else priors(i, j))
            if result.found:
                candidates.append((i, j, result))
    candidates.sort(key=lambda c: (c[2].statistics.log10_chance_probability, -len(c[2].supports)))
    sets = _Sets()
    out = JoinedNames([], tried=tried, window_links=[0] * n)
    for i, j, result in candidates:
        trial = sets.copy()
        why = ""
        pairs = [((i, int(a)), (j, int(b))) for a, b in result.supports]
        for a, b in pairs:
            why = trial.conflict(a, b)
            if why:
                break
            trial.union(a, b)
        if why:
            out.refused.append(Refusal((i, j), len(pairs), why))
            continue
        sets = trial
        out.found.append((i, j, result))
        out.joins.extend(pairs)
        out.window_links[i] += 1
        out.window_links[j] += 1
    roots: dict[tuple[int, int], int] = {}
    for w, m in enumerate(maps):
        out.names.append(np.array([roots.setdefault(sets.root((w, r)), len(roots)) for r in range(len(m))],
                                  np.int64))
    out.window_components = _components(n, [(i, j) for i, j, _ in out.found])
    return out


def odometry_prior(starts: np.ndarray, travelled: np.ndarray, sigma_xy: tuple[float, float],
                   sigma_theta: tuple[float, float]) -> Callable[[int, int], StartPrior]:
    """Priors from the odometry between the windows' frames: starts (W, 3) each window frame's dead-reckoned pose
    (calibrated odometry, one frame for all windows), travelled (W,) the odometry's path length at each; the mean is
    the odometry's relative pose, the σ independent and growing with the path d between the two frames:
    σ_xy = a + b·d (m), σ_θ = c + e·d (rad), from ``sigma_xy`` = (a, b) and ``sigma_theta`` = (c, e)."""
    starts = np.asarray(starts, float).reshape(-1, 3)
    travelled = np.asarray(travelled, float).reshape(-1)

    def prior(i: int, j: int) -> StartPrior:
        d = abs(float(travelled[j] - travelled[i]))
        return StartPrior.from_sigmas(between(starts[i], starts[j]), sigma_xy[0] + sigma_xy[1] * d,
                                      sigma_theta[0] + sigma_theta[1] * d, source="odometry")

    return prior


def _components(n: int, edges: list[tuple[int, int]]) -> int:
    parent = list(range(n))

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for i, j in edges:
        parent[root(i)] = root(j)
    return len({root(x) for x in range(n)})


def sighting_names(windows: Sequence[Window], joined: JoinedNames, n_sightings: int) -> np.ndarray:
    """(n_sightings,) every sighting's joined name (−1: unnamed, or in no window)."""
    out = np.full(n_sightings, -1, np.int64)
    for w, names in zip(windows, joined.names, strict=True):
        named = w.sighting_landmark >= 0
        out[w.sightings[named]] = names[w.sighting_landmark[named]]
    return out


def with_names(log: RangeBearingLog, names: np.ndarray) -> RangeBearingLog:
    """The log with each sighting's name in place of its identity, the unnamed sightings left out."""
    keep = np.asarray(names) >= 0
    return dataclasses.replace(log, sighting_times=log.sighting_times[keep], ranges=log.ranges[keep],
                               bearings=log.bearings[keep], landmark_ids=np.asarray(names)[keep].astype(np.int64))
