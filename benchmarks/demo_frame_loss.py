"""Why a rendered demo robot loses its frame: its pose error against the filter's σ, the motion, what it sees, the
wrong associations and the odometry's own error, frame by frame; and replays of the same frames with exact or
de-biased odometry, another stereo matcher, readings left out, more particles or other filter draws.

Run from the repository root, on a ``p3at demo --seed S --out DIR --log-sensors`` folder (``<robot>-log/``, the TUM
files, ``<robot>-filter.npz`` or ``<robot>.npz``):

    OPENBLAS_NUM_THREADS=1 nice -n 5 .venv/bin/python -m benchmarks.demo_frame_loss DIR [--robot robot1]
        [--cache FILE] [--matching logged|full-row|wide] [--near-frame-share S] [--drop-near]
        [--odometry logged|truth|unbiased] [--particles N] [--filter-seed K]
        [--from T0] [--to T1] [--every N] [--turns] [--readings] [--json FILE] [--save-map FILE] [--save-smoothed FILE]

or, from the truth alone, each robot's near-wall episodes beside its self-check, for any number of demo folders:

    OPENBLAS_NUM_THREADS=1 nice -n 5 .venv/bin/python -m benchmarks.demo_frame_loss --episodes DIR [DIR ...]

The first run replays the sensor log's frames through the front end once (a minute or two) and keeps each processed
frame's observations, its odometry (interpolated from the logged SIPs as the live SLAM thread did), the true pose at
its time and each reading's true world point (the surface point behind its left pixel at the true pose,
``StereoRenderer.true_points``, as ``demo_smoothing.landmark_truth``) in ``--cache`` (default
/tmp/demo_frame_loss/<folder>-<robot>-<matching>.npz). Every run then replays the filter alone from it through a fresh
``runtime.onboard.SlamCore`` (the mission's own step, frames given as observations): with the log's settings and the
logged odometry it rebuilds the demo's filter map bit for bit, which is checked and printed (``same_as_demo 1``);
``--save-smoothed`` smooths it as ``--smooth`` does (keyframes' readings; on demo seed 4 robot 1 the demo's smoothed
map bit for bit).

Variants (each on the same frames):
``--odometry truth``: the true poses as odometry (exact odometry); ``--odometry unbiased``: the virtual robot's
  systematic wheel errors taken out of each increment (turn × wheelbase scale / distance scale, distance / distance
  scale, from ``mocks.p3at.options.OdometryErrors.realistic``, what ``p3at demo --odometry realistic`` drives with),
  its random part kept. ``--particles`` and ``--filter-seed`` replace the log's.
``--matching full-row``: each left corner's match searched along the whole row (the ratio test and the left-right
  check over every disparity), then refused when its disparity is beyond the head's range (``max_disparity``): the
  range as a test, not a search window that hands a corner whose true match lies beyond it the best wrong one
  inside; the matches so refused are counted per frame. ``--matching wide``: the whole row searched and kept.
``--near-frame-share S`` (with ``full-row``): every reading of a frame whose refused matches are more than S of its
  matches is left out (the scene is nearer than the head can measure, fx·B / max_disparity = 0.487 m on the demo's
  head; the in-range matches of such a frame are mostly false too).
``--drop-near``: an oracle, the readings whose *true* point is nearer than that minimum depth left out.

Printed, per window of ``--every`` frames between ``--from`` and ``--to``: the best particle's position and heading
error against the truth (start frame), the filter's stated σθ (the drift tracker's, the pose's uncertainty relative to
the start, which the exported map carries) and |eθ| in those σ; the weighted cloud's σθ and the truth's pose NEES in
the cloud (median over the window); the odometry's heading error; the true speed and the largest turn rate; ESS and
the share of frames resampled; readings per frame, the best particle's matches, new landmarks, and its *wrong*
matches (a reading given to a landmark whose first reading's true point is more than ``WRONG`` m from the reading's
own true point; then more than ``WRONG_FAR`` m; of the matches judged, both true points known); the self-check's
CUSUM statistic. Then a summary: when the frame was first lost (|eθ| beyond 3 stated σ and ``LOST_RAD``), the
self-check's first alarm, the largest |eθ|, ATE, the final error, the wrong matches before and after the loss.
``--turns``: each turn on the spot of the true trajectory (``demo_frame_errors.turns_on_the_spot``): its time, the
angle turned, the odometry's error over it, the motion model's σθ for it (the random walk's ``increment_variance``
summed over its increments) and that error in σ; the best particle's heading error before and after, and the wrong
matches in the 10 s after it.
``--readings``: the readings of the frames in [``--from``, ``--to``] and of all the others against their true
points (in the robot's true frame): readings a frame, the median |measured − true|, the share beyond χ²₃ 99 % of
their own covariance, the median true and measured range.
``--episodes``: per folder and robot, the frames at which most of the middle row of the left image (``NEAR_COLUMNS``)
looks at a surface nearer than the head's minimum depth, grouped into episodes, beside the filter map's and the
published map's self-check verdicts.

Session 52 (C), demo seed 4 robot 1 (lost at 120 s, flagged at 123.7 s): from 116.5 to 122.3 s it turns on the
spot facing a wall 0.30 m from the camera, nearer than the head's 0.487 m; 97 % of its readings there lie beyond χ²₃
99 % of their own covariance (median error 0.63 m), against 4–7 % elsewhere; the filter weighs and resamples on
them (ESS 11) and its heading leaves the odometry's by up to 0.2 rad. With ``--matching full-row
--near-frame-share 0.3`` no alarm and no loss in 9 of 9 draws (as logged: 4 of 9 flagged, 3 of 9 stay lost; exact
odometry: 5 of 8 flagged, 0 stay lost).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from estimation.geometry import between, compose, inverse, transform_points, wrap_angle  # noqa: E402
from runtime.commands.options import non_negative_float, non_negative_int, positive_int  # noqa: E402

WRONG = 0.10          # m: a match whose reading's true point is this far from its landmark's first reading's joins
WRONG_FAR = 0.50      # m: ... this far: not a neighbouring corner or a ray that slipped off an edge, another place
LOST_RAD = 0.05       # rad: a heading error this large (and beyond 3 stated σ) counts as the frame lost
CHI2_3_99 = 11.345    # χ²₃ 99 %: a reading beyond it of its own covariance is not what the head claims


# -- pure functions ------------------------------------------------------------------------------------------------
def wrong_matches(matches: np.ndarray, reading_points: np.ndarray, origin: dict[int, np.ndarray],
                  radius: float = WRONG) -> tuple[int, int]:
    """(judged, wrong): of the readings matched to a landmark (``matches`` (N,) landmark id or -1) whose own true
    point (``reading_points`` (N, 3), NaN: unknown) and whose landmark's first reading's true point (``origin``) are
    both known, how many lie more than ``radius`` apart."""
    judged = wrong = 0
    for j in np.flatnonzero(np.asarray(matches) >= 0):
        first = origin.get(int(matches[j]))
        p = reading_points[j]
        if first is None or not (np.all(np.isfinite(first)) and np.all(np.isfinite(p))):
            continue
        judged += 1
        wrong += int(np.linalg.norm(first - p) > radius)
    return judged, wrong


def pose_nees(pose: np.ndarray, truth: np.ndarray, cov: np.ndarray) -> float:
    """(pose − truth)ᵀ cov⁻¹ (pose − truth), the heading difference wrapped; inf when cov is singular."""
    e = np.asarray(pose, float) - np.asarray(truth, float)
    e[2] = wrap_angle(e[2])
    try:
        return float(e @ np.linalg.solve(np.asarray(cov, float), e))
    except np.linalg.LinAlgError:
        return float("inf")


def unbias_increment(delta: np.ndarray, distance_scale: float, wheelbase_scale: float) -> np.ndarray:
    """An odometry increment (dx, dy, dθ) with a differential drive's systematic wheel errors taken out.

    The firmware measures each wheel's travel × ``distance_scale`` and turns by (r − l) / (track × wheelbase_scale),
    so the measured turn is the true one × distance_scale / wheelbase_scale and the distance × distance_scale; the
    chord is taken at half the turn (the firmware's midpoint integration), its direction (forward or back) kept."""
    dx, dy, dtheta = map(float, delta)
    d = np.hypot(dx, dy) / distance_scale
    turn = dtheta * wheelbase_scale / distance_scale
    forward = 1.0 if dx * np.cos(dtheta / 2) + dy * np.sin(dtheta / 2) >= 0 else -1.0
    return np.array([forward * d * np.cos(turn / 2), forward * d * np.sin(turn / 2), turn])


def compose_increments(first: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """(T, 3) poses: ``first`` then each of the (T − 1, 3) increments composed in turn."""
    out = [np.asarray(first, float)]
    for d in deltas:
        out.append(compose(out[-1], d))
    return np.array(out)


def turn_sigma(deltas: np.ndarray, config, seconds: np.ndarray) -> float:
    """The motion model's σθ of a chain of increments (T, 3): √Σ of its random-walk heading variances."""
    from estimation.fastslam.motion import increment_variance

    return float(np.sqrt(np.sum(increment_variance(np.asarray(deltas, float), config, np.asarray(seconds))[:, 2])))


# -- 1. the frames, once -------------------------------------------------------------------------------------------
def record(folder: Path, robot: str, cache: Path, matching: str = "logged") -> dict:
    """The log's processed frames as observations, with their odometry, true pose and readings' true points
    (``matching``: the stereo matcher as logged, or ``full-row`` / ``wide``, module docstring)."""
    if cache.is_file():
        with np.load(cache, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    from benchmarks.fusion_sim import load_world
    from estimation.frontend import FrontEnd
    from estimation.observations import StereoObservations
    from mocks.stereo_head import default_calibration
    from mocks.stereo_head.renderer import StereoRenderer
    from runtime.replay import _frames, core_and_odometry, onboard_config_from_log
    from runtime.sensorlog import SensorLog
    from runtime.trajectories import planar, read_tum

    log = SensorLog(folder / f"{robot}-log")
    config = onboard_config_from_log(log)
    core, odometry = core_and_odometry(log, config)
    start = np.asarray(log.metadata["true_start_pose"], float)
    truth = planar(read_tum(folder / f"{robot}-truth.tum"))
    renderer = StereoRenderer(load_world(), default_calibration())
    processed = {int(r["seq"]) for r in log.records("processed")}
    keep: dict[str, list] = {k: [] for k in ("t", "seq", "odometry", "truth", "counts", "points", "covariances",
                                             "descriptors", "pixels", "true_points", "beyond")}
    front_end, limit = core.front_end, config.frontend.matching.max_disparity
    for frame in _frames(log, config.fastslam.descriptor_size):
        if frame.seq not in processed:
            continue
        pose = odometry.interpolate(frame.t)
        if pose is None:
            continue
        obs = frame.observations
        if obs is None and matching == "logged":
            obs = front_end.match(frame.left, frame.right).to_observations(frame.t)
        elif obs is None:
            if front_end is core.front_end:   # the whole row searched: the image's width
                front_end = FrontEnd(replace(config.frontend, matching=replace(
                    config.frontend.matching, max_disparity=float(np.asarray(frame.left).shape[1]))))
            m = front_end.match(frame.left, frame.right)
            keep["beyond"].append(int(np.sum(m.disparities > limit)))
            rows = np.flatnonzero(m.disparities <= limit) if matching == "full-row" else np.arange(len(m))
            obs = StereoObservations(m.points_base[rows], m.covariances_base[rows], m.descriptors[rows],
                                     m.left_pixels[rows], float(frame.t))
        k = int(np.clip(np.searchsorted(truth[:, 0], frame.t), 0, len(truth) - 1))
        if abs(truth[k, 0] - frame.t) > 1e-6:
            raise SystemExit(f"{folder}: {robot}-truth.tum has no row at the frame of {frame.t:.3f} s")
        pixels = np.asarray(obs.pixels, float).reshape(-1, 2)
        keep["true_points"].append(renderer.true_points(compose(start, truth[k, 1:]), pixels, "left", rectified=True)
                                   if len(pixels) else np.zeros((0, 3)))
        for key, value in (("t", frame.t), ("seq", frame.seq), ("odometry", np.asarray(pose, float)),
                           ("truth", truth[k, 1:]), ("counts", len(obs)),
                           ("points", np.asarray(obs.points, float).reshape(-1, 3)),
                           ("covariances", np.asarray(obs.covariances, float).reshape(-1, 3, 3)),
                           ("descriptors", np.asarray(obs.descriptors, np.float32)), ("pixels", pixels)):
            keep[key].append(value)
    out = {k: (np.concatenate(v) if k in ("points", "covariances", "descriptors", "pixels", "true_points")
               else np.array(v)) for k, v in keep.items()}
    out["start"] = start
    out["matching"] = np.array(matching)
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, **out)
    return out


# -- 2. the filter alone, from the frames --------------------------------------------------------------------------
def odometry_poses(rec: dict, kind: str) -> np.ndarray:
    """(T, 3) the odometry poses the filter is given: as logged, the truth, or the logged de-biased."""
    if kind == "logged":
        return rec["odometry"]
    if kind == "truth":
        return rec["truth"]
    from mocks.p3at.options import OdometryErrors

    e = OdometryErrors.realistic()
    odo = rec["odometry"]
    deltas = [unbias_increment(between(odo[i - 1], odo[i]), e.distance_scale, e.wheelbase_scale)
              for i in range(1, len(odo))]
    return compose_increments(odo[0], np.array(deltas).reshape(-1, 3))


def near_readings(rec: dict, min_depth: float, head_x: float) -> np.ndarray:
    """(R,) bool: the readings whose true point lies nearer than ``min_depth`` ahead of the camera (its depth: the
    true point's x in the robot's true frame less the head's ``head_x``); an unknown true point is not near."""
    bounds = np.r_[0, np.cumsum(rec["counts"])]
    out = np.zeros(bounds[-1], bool)
    for i in range(len(rec["t"])):
        s = slice(bounds[i], bounds[i + 1])
        local = transform_points(inverse(compose(rec["start"], rec["truth"][i])), rec["true_points"][s])
        with np.errstate(invalid="ignore"):
            out[s] = local[:, 0] - head_x < min_depth
    return out


def near_frames(beyond: np.ndarray, kept: np.ndarray, share: float) -> np.ndarray:
    """(T,) bool: the frames whose stereo matches found beyond the head's disparity range (``beyond`` (T,), along
    the whole row) are more than ``share`` of all their matches (with the ``kept`` (T,) in range): a scene nearer
    than the head can measure, where the in-range matches are mostly false too."""
    beyond, kept = np.asarray(beyond, float), np.asarray(kept, float)
    total = beyond + kept
    return (total > 0) & (beyond > share * np.maximum(total, 1e-12))


def run_filter(folder: Path, robot: str, rec: dict, kind: str, particles: int | None, filter_seed: int | None,
               drop_near: bool = False, near_frame_share: float | None = None, smooth: bool = False) -> dict:
    """Per-frame arrays of a filter replay (module docstring) and the final map's figures; with ``smooth`` the
    mission's smoothed map too (``out["smoothed"]``: the core keeps keyframes' readings as ``--smooth`` does)."""
    from estimation.observations import StereoObservations
    from runtime.onboard import CameraFrame, SlamCore
    from runtime.replay import onboard_config_from_log
    from runtime.sensorlog import SensorLog

    config = onboard_config_from_log(SensorLog(folder / f"{robot}-log"), particles=particles, seed=filter_seed)
    config = replace(config, keep_readings=smooth)
    core = SlamCore(robot, config)
    core.metadata["true_start_pose"] = [float(v) for v in rec["start"]]   # as runtime.replay's core: scored maps
    slam = core.slam
    reports = []
    update = slam.update
    slam.update = lambda obs: reports.append(update(obs)) or reports[-1]   # the report the step drops
    odometry = odometry_poses(rec, kind)
    bounds = np.r_[0, np.cumsum(rec["counts"])]
    keep = np.ones(bounds[-1], bool)
    if drop_near:   # the oracle: the stereo head's minimum depth fx·B / max_disparity, from the log's settings
        g = config.frontend.geometry
        keep = ~near_readings(rec, g.fx * g.baseline / config.frontend.matching.max_disparity, g.head_pose[0])
    if near_frame_share is not None:   # a full-row cache: its frames with too many matches beyond the range dropped
        if _matching(rec) != "full-row":
            raise SystemExit("--near-frame-share needs --matching full-row (the matches beyond the range)")
        frames = near_frames(rec["beyond"], rec["counts"], near_frame_share)
        keep &= ~np.repeat(frames, rec["counts"])
    origin: dict[int, np.ndarray] = {}
    rows: dict[str, list] = {k: [] for k in ("best", "drift", "cloud_mean", "cloud_cov", "ess", "resampled",
                                             "n_obs", "best_matched", "best_new", "judged", "wrong", "wrong_far",
                                             "cusum", "lost")}
    for i, t in enumerate(rec["t"]):
        s = bounds[i] + np.flatnonzero(keep[bounds[i]:bounds[i + 1]])
        obs = StereoObservations(rec["points"][s], rec["covariances"][s], rec["descriptors"][s], rec["pixels"][s],
                                 float(t))
        core.step(CameraFrame(float(t), int(rec["seq"][i]), observations=obs), odometry[i])
        report, points = reports[-1], rec["true_points"][s]
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            origin.setdefault(int(report.new_landmark_ids[j]), points[j])
        judged, wrong = wrong_matches(report.best_matches, points, origin)
        wrong_far = wrong_matches(report.best_matches, points, origin, WRONG_FAR)[1]
        for key, value in (("best", slam.best_pose()), ("drift", slam.drift.robot.copy()),
                           ("cloud_mean", report.pose_mean), ("cloud_cov", report.pose_covariance),
                           ("ess", report.ess), ("resampled", report.resampled), ("n_obs", report.n_observations),
                           ("best_matched", int(np.sum(report.best_matches >= 0))),
                           ("best_new", int(np.sum(report.new_landmark_ids >= 0))), ("judged", judged),
                           ("wrong", wrong), ("wrong_far", wrong_far), ("cusum", slam.self_check.statistic),
                           ("lost", slam.self_check.lost)):
            rows[key].append(value)
    out: dict = {k: np.array(v, float) for k, v in rows.items()}
    # the start frame: the first frame's odometry pose is the map's origin, and the truth's start is its own
    out["truth"] = np.array([between(rec["truth"][0], p) for p in rec["truth"]])
    out["odometry"] = np.array([between(odometry[0], p) for p in odometry])
    out["t"] = rec["t"]
    exported = core.best_map()
    out["map"] = exported
    if smooth:
        out["smoothed"] = core.smoothed_map(exported).landmark_map
    out["landmarks"] = np.array(len(exported))
    out["same"] = np.array(-1)
    if kind == "logged" and particles is None and filter_seed is None and _matching(rec) == "logged" \
            and not drop_near:
        from estimation.landmark_map import LandmarkMap

        files = [folder / f"{robot}-filter.npz", folder / f"{robot}.npz"]
        demo = LandmarkMap.load(next(p for p in files if p.is_file()))
        out["same"] = np.array(int(len(demo) == len(exported) and np.array_equal(demo.positions, exported.positions)))
    out["alarm_t"] = np.array(_first(out["t"], out["lost"] > 0))
    return out


def _matching(rec: dict) -> str:
    return str(rec["matching"]) if "matching" in rec else "logged"


def _first(t: np.ndarray, mask: np.ndarray) -> float:
    k = np.flatnonzero(mask)
    return float(t[k[0]]) if len(k) else float("nan")


# -- 2b. where the head faces a scene nearer than it can measure (the truth alone) ----------------------------------
NEAR_COLUMNS = (80.0, 200.0, 320.0, 440.0, 560.0)   # px: the rectified left image's columns cast along its middle row


def group_episodes(t: np.ndarray, mask: np.ndarray, gap: float = 1.0) -> list[tuple[float, float, int]]:
    """(first, last, frames) of each run of ``mask`` (T,) over times ``t`` (T,), runs less than ``gap`` s apart
    joined."""
    out: list[list] = []
    for k in np.flatnonzero(mask):
        if out and t[k] - out[-1][1] < gap:
            out[-1][1] = float(t[k])
            out[-1][2] += 1
        else:
            out.append([float(t[k]), float(t[k]), 1])
    return [tuple(e) for e in out]


def near_wall_frames(folder: Path, robot: str, renderer, min_depth: float, head_x: float) -> tuple[np.ndarray,
                                                                                                    np.ndarray]:
    """(times (T,), near (T,) bool): the frames of ``<robot>-truth.tum`` at which most of the middle row of the left
    image (``NEAR_COLUMNS``) looks at a surface nearer than ``min_depth`` ahead of the camera."""
    from runtime.trajectories import planar, read_tum

    with np.load(folder / f"{robot}.npz", allow_pickle=False) as z:
        start = np.asarray(json.loads(bytes(z["meta"]).decode())["metadata"]["true_start_pose"], float)
    truth = planar(read_tum(folder / f"{robot}-truth.tum"))
    pixels = np.column_stack([NEAR_COLUMNS, np.full(len(NEAR_COLUMNS), 239.5)])
    near = np.zeros(len(truth), bool)
    for k, row in enumerate(truth):
        pose = compose(start, row[1:])
        local = transform_points(inverse(pose), renderer.true_points(pose, pixels, "left", rectified=True))
        with np.errstate(invalid="ignore"):
            near[k] = np.sum(local[:, 0] - head_x < min_depth) > len(NEAR_COLUMNS) / 2
    return truth[:, 0], near


def print_episodes(folders: list[Path]) -> None:
    """Per demo folder and robot: the near-wall episodes (truth alone) and the robot's self-check verdict."""
    from benchmarks.fusion_sim import load_world
    from estimation.frontend import FrontEndConfig
    from mocks.stereo_head import default_calibration
    from mocks.stereo_head.renderer import StereoRenderer

    renderer = StereoRenderer(load_world(), default_calibration())
    front = FrontEndConfig()
    g = front.geometry
    min_depth = g.fx * g.baseline / front.matching.max_disparity
    print(f"near: most of the middle image row looks at a surface nearer than {min_depth:.3f} m (fx·B / max "
          f"disparity) ahead of the camera")
    print("| folder | robot | near-wall episodes (s, frames) | filter map's self-check | published map's |")
    print("|---|---|---|---|---|")
    for folder in folders:
        for robot in ("robot1", "robot2"):
            if not (folder / f"{robot}-truth.tum").is_file():
                continue
            t, near = near_wall_frames(folder, robot, renderer, min_depth, g.head_pose[0])
            episodes = "; ".join(f"{a:.1f}–{b:.1f} ({n})" for a, b, n in group_episodes(t, near)) or "none"
            verdicts = [_verdict(folder / name) for name in (f"{robot}-filter.npz", f"{robot}.npz")]
            print(f"| {folder.name} | {robot} | {episodes} | {verdicts[0]} | {verdicts[1]} |")


def _verdict(path: Path) -> str:
    """A saved map's self-check: "flagged at T s" (its first alarm), "not flagged", or "—" (no file, no check)."""
    if not path.is_file():
        return "—"
    with np.load(path, allow_pickle=False) as z:
        check = json.loads(bytes(z["meta"]).decode())["metadata"].get("self_check") or {}
    if not check:
        return "—"
    alarms = check.get("alarms") or []
    return f"flagged at {alarms[0]['t']:.1f} s" if check.get("lost") and alarms else \
        ("flagged" if check.get("lost") else "not flagged")


# -- 2c. the readings themselves against the truth ------------------------------------------------------------------
def reading_errors(points: np.ndarray, covariances: np.ndarray, true_local: np.ndarray) -> dict[str, float]:
    """Readings (N, 3) in the robot frame with their covariances (N, 3, 3) against their true points in the robot's
    true frame (N, 3; NaN: unknown): how many are scored, the median |measured − true|, the share beyond χ²₃ 99 % of
    their own covariance, the median true and measured horizontal range."""
    ok = np.all(np.isfinite(true_local), axis=1)
    e = points[ok] - true_local[ok]
    if not len(e):
        return {"scored": 0, "median_error": float("nan"), "beyond": float("nan"), "true_range": float("nan"),
                "range": float("nan")}
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(covariances[ok], e[:, :, None])[:, :, 0])
    return {"scored": int(ok.sum()), "median_error": float(np.median(np.linalg.norm(e, axis=1))),
            "beyond": float(np.mean(nees > CHI2_3_99)),
            "true_range": float(np.median(np.hypot(true_local[ok, 0], true_local[ok, 1]))),
            "range": float(np.median(np.hypot(points[ok, 0], points[ok, 1])))}


def print_readings(rec: dict, t0: float, t1: float) -> None:
    """The readings of the frames in [t0, t1] and of the others, scored against the truth (``reading_errors``)."""
    bounds = np.r_[0, np.cumsum(rec["counts"])]
    local = np.full((bounds[-1], 3), np.nan)
    for i in range(len(rec["t"])):
        s = slice(bounds[i], bounds[i + 1])
        local[s] = transform_points(inverse(compose(rec["start"], rec["truth"][i])), rec["true_points"][s])
    inside = np.repeat((rec["t"] >= t0) & (rec["t"] <= t1), rec["counts"])
    print("| frames | readings a frame | median \\|measured − true\\| | beyond χ²₃ 99 % of their covariance | "
          "true / measured range |")
    print("|---|---|---|---|---|")
    for name, rows, frames in ((f"{t0:g}–{t1:g} s", inside, np.sum((rec["t"] >= t0) & (rec["t"] <= t1))),
                               ("the others", ~inside, np.sum((rec["t"] < t0) | (rec["t"] > t1)))):
        r = reading_errors(rec["points"][rows], rec["covariances"][rows], local[rows])
        print(f"| {name} | {rows.sum() / max(int(frames), 1):.1f} | {r['median_error']:.3f} m | "
              f"{100 * r['beyond']:.0f} % | {r['true_range']:.2f} / {r['range']:.2f} m |")


# -- 3. figures ----------------------------------------------------------------------------------------------------
def errors(d: dict) -> dict[str, np.ndarray]:
    """Per frame: position / heading error, stated σθ (drift), cloud σθ, truth's NEES in the cloud, odometry error."""
    e_xy = np.hypot(*(d["best"][:, :2] - d["truth"][:, :2]).T)
    e_th = wrap_angle(d["best"][:, 2] - d["truth"][:, 2])
    sd_drift = np.sqrt(np.maximum(d["drift"][:, 2, 2], 0.0))
    sd_pos = np.sqrt(np.maximum(d["drift"][:, 0, 0] + d["drift"][:, 1, 1], 0.0))
    sd_cloud = np.sqrt(np.maximum(d["cloud_cov"][:, 2, 2], 0.0))
    in_cloud = np.array([pose_nees(m, tr, c + 1e-12 * np.eye(3))
                         for m, tr, c in zip(d["cloud_mean"], d["truth"], d["cloud_cov"], strict=True)])
    odo_th = wrap_angle(d["odometry"][:, 2] - d["truth"][:, 2])
    t = d["t"]
    dt = np.maximum(np.diff(t, prepend=t[0] - 1.0), 1e-9)
    speed = np.r_[0.0, np.hypot(*np.diff(d["truth"][:, :2], axis=0).T)] / dt
    rate = np.r_[0.0, np.abs(wrap_angle(np.diff(d["truth"][:, 2])))] / dt
    return {"xy": e_xy, "theta": e_th, "sd_theta": sd_drift, "sd_xy": sd_pos, "sd_cloud": sd_cloud,
            "cloud_nees": in_cloud, "odo_theta": odo_th, "speed": speed, "rate": rate}


def print_timeline(d: dict, t0: float, t1: float, every: int) -> None:
    e = errors(d)
    print("| t (s) | error m / rad | σθ stated | \\|eθ\\|/σ | σθ cloud | truth NEES in cloud | odometry eθ | "
          "speed m/s / turn rad/s | ESS / resampled | readings / best matched / new / wrong (judged) | CUSUM |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for k in range(0, len(d["t"]), every):
        if not t0 <= d["t"][k] <= t1:
            continue
        s = slice(k, k + every)
        print(f"| {d['t'][k]:.1f} | {e['xy'][k]:.3f} / {e['theta'][k]:+.3f} | {e['sd_theta'][k]:.3f} | "
              f"{abs(e['theta'][k]) / max(e['sd_theta'][k], 1e-9):.1f} | {e['sd_cloud'][k]:.3f} | "
              f"{np.median(e['cloud_nees'][s]):.0f} | {e['odo_theta'][k]:+.3f} | {np.mean(e['speed'][s]):.2f} / "
              f"{np.max(e['rate'][s]):.2f} | {np.mean(d['ess'][s]):.0f} / {np.mean(d['resampled'][s]):.1f} | "
              f"{np.mean(d['n_obs'][s]):.0f} / {np.mean(d['best_matched'][s]):.1f} / {np.mean(d['best_new'][s]):.1f}"
              f" / {np.sum(d['wrong'][s]):.0f}, {np.sum(d['wrong_far'][s]):.0f} ({np.sum(d['judged'][s]):.0f}) | "
              f"{d['cusum'][k]:.1f} |")


def summary(d: dict) -> dict:
    e = errors(d)
    t = d["t"]
    lost = (np.abs(e["theta"]) > 3 * e["sd_theta"]) & (np.abs(e["theta"]) > LOST_RAD)
    alarm = float(d["alarm_t"])
    cut = _first(t, lost)
    before = t < cut if np.isfinite(cut) else np.ones(len(t), bool)
    return {"frames": len(t), "same_as_demo": int(d["same"]), "landmarks": int(d["landmarks"]),
            "ate_m": float(np.sqrt(np.mean(e["xy"] ** 2))), "final_m": float(e["xy"][-1]),
            "final_rad": float(e["theta"][-1]), "max_abs_theta": float(np.max(np.abs(e["theta"]))),
            "first_lost_s": cut, "alarm_s": alarm,
            "wrong_before": int(np.sum(d["wrong"][before])), "wrong_far_before": int(np.sum(d["wrong_far"][before])),
            "judged_before": int(np.sum(d["judged"][before])),
            "wrong_after": int(np.sum(d["wrong"][~before])), "wrong_far_after": int(np.sum(d["wrong_far"][~before])),
            "judged_after": int(np.sum(d["judged"][~before])),
            "odometry_final_rad": float(e["odo_theta"][-1])}


def print_turns(d: dict, rec: dict, config) -> list[dict]:
    from benchmarks.demo_frame_errors import turns_on_the_spot

    e = errors(d)
    t = d["t"]
    rows = np.column_stack([t, d["truth"]])
    out = []
    print("| turn (s) | true turn rad | odometry error rad | model σθ | error / σ | best eθ before → after | "
          "wrong (judged) 10 s after |")
    print("|---|---|---|---|---|---|---|")
    for a, b in turns_on_the_spot(rows):
        a0 = max(a - 1, 0)
        true_turn = float(np.sum(wrap_angle(np.diff(d["truth"][a0:b + 1, 2]))))
        odo_turn = float(np.sum(wrap_angle(np.diff(d["odometry"][a0:b + 1, 2]))))
        deltas = np.array([between(d["odometry"][k - 1], d["odometry"][k]) for k in range(a0 + 1, b + 1)])
        sigma = turn_sigma(deltas, config, np.diff(t[a0:b + 1]))
        after = (t > t[b]) & (t <= t[b] + 10.0)
        row = {"t0": float(t[a0]), "t1": float(t[b]), "turn": true_turn, "odometry_error": odo_turn - true_turn,
               "sigma": sigma, "before": float(e["theta"][a0]), "after": float(e["theta"][min(b + 1, len(t) - 1)]),
               "wrong_after": int(np.sum(d["wrong"][after])), "judged_after": int(np.sum(d["judged"][after]))}
        out.append(row)
        print(f"| {row['t0']:.1f}–{row['t1']:.1f} | {true_turn:+.3f} | {row['odometry_error']:+.4f} | {sigma:.4f} | "
              f"{abs(row['odometry_error']) / sigma:.2f} | {row['before']:+.3f} → {row['after']:+.3f} | "
              f"{row['wrong_after']} ({row['judged_after']}) |")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("demo", type=Path, nargs="+", help="a `p3at demo --out DIR --log-sensors` folder (with "
                        "--episodes: any number of `p3at demo --out` folders)")
    parser.add_argument("--episodes", action="store_true",
                        help="only list each robot's near-wall episodes from the truth (module docstring)")
    parser.add_argument("--robot", default="robot1")
    parser.add_argument("--cache", type=Path, default=None, metavar="FILE")
    parser.add_argument("--odometry", choices=("logged", "truth", "unbiased"), default="logged")
    parser.add_argument("--matching", choices=("logged", "full-row", "wide"), default="logged",
                        help="the stereo matcher the frames go through (module docstring)")
    parser.add_argument("--drop-near", action="store_true",
                        help="an oracle: leave out the readings whose true point is nearer than the head's minimum "
                             "depth (module docstring)")
    parser.add_argument("--near-frame-share", type=non_negative_float, default=None, metavar="S",
                        help="with --matching full-row: leave out every reading of a frame whose matches beyond the "
                             "head's disparity range are more than S of its matches (module docstring)")
    parser.add_argument("--particles", type=positive_int, default=None)
    parser.add_argument("--filter-seed", type=non_negative_int, default=None)
    parser.add_argument("--from", dest="t0", type=non_negative_float, default=0.0)
    parser.add_argument("--to", dest="t1", type=non_negative_float, default=1e9)
    parser.add_argument("--every", type=positive_int, default=8)
    parser.add_argument("--turns", action="store_true")
    parser.add_argument("--readings", action="store_true",
                        help="also score the readings of the frames in [--from, --to] and of the others")
    parser.add_argument("--json", type=Path, default=None, metavar="FILE", help="write the summary (and turns)")
    parser.add_argument("--save-map", type=Path, default=None, metavar="FILE",
                        help="write the replayed filter's map (as the mission exports it), for `p3at fuse`")
    parser.add_argument("--save-smoothed", type=Path, default=None, metavar="FILE",
                        help="smooth the replayed map as the mission does (keyframes' readings) and write it")
    args = parser.parse_args(argv)
    if args.episodes:
        print_episodes(args.demo)
        return 0
    if len(args.demo) != 1:
        raise SystemExit("one demo folder at a time (or --episodes)")
    args.demo = args.demo[0]
    if not (args.demo / f"{args.robot}-log").is_dir():
        raise SystemExit(f"{args.demo}: no {args.robot}-log/ (run the demo with --log-sensors)")
    import cv2

    cv2.setNumThreads(1)
    cache = args.cache or Path("/tmp/demo_frame_loss") / f"{args.demo.name}-{args.robot}-{args.matching}.npz"
    rec = record(args.demo, args.robot, cache, args.matching)
    if _matching(rec) != args.matching:
        raise SystemExit(f"{cache} holds the frames of --matching {_matching(rec)}, not {args.matching}")
    d = run_filter(args.demo, args.robot, rec, args.odometry, args.particles, args.filter_seed, args.drop_near,
                   args.near_frame_share, args.save_smoothed is not None)
    frames_out = "" if args.near_frame_share is None else f", near frames (share > {args.near_frame_share:g}) out"
    print(f"{args.demo} {args.robot}: matching {args.matching}{', near readings dropped' * args.drop_near}"
          f"{frames_out}, "
          f"odometry {args.odometry}, particles "
          f"{args.particles or 'as logged'}, "
          f"filter seed {'as logged' if args.filter_seed is None else args.filter_seed}")
    print_timeline(d, args.t0, args.t1, args.every)
    if args.readings:
        print_readings(rec, args.t0, args.t1)
    s = summary(d)
    print("summary: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}" for k, v in s.items()))
    turns = []
    if args.turns:
        from runtime.replay import onboard_config_from_log
        from runtime.sensorlog import SensorLog

        config = onboard_config_from_log(SensorLog(args.demo / f"{args.robot}-log")).fastslam
        turns = print_turns(d, rec, config)
    for key, path in (("map", args.save_map), ("smoothed", args.save_smoothed)):
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            d[key].save(path)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "summary": s,
                                         "turns": turns}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
