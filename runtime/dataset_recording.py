"""A landmark data set's run (``p3at slam dataset ... --rerun SINK``) as a Rerun recording, beside its ground truth.

What a reader sees, in the robot's 2-D map (its start frame, as the map file): the estimated path, the dead
reckoning and the true path (Vicon on MRCLAM) growing over the log's time, the final map's landmarks with the true
ones labelled by id under them, and the pose NEES over time (plots/<robot>/pose_nees); in the 3-D world the same
placed at the robot's true start, with the landmarks' 1-σ ellipsoids shown (the layout is
:func:`runtime.rerun_style.dataset_blueprint`: whether they cover the truth is what a run with ground truth shows). The
map's arrays and the run's figures and warnings are in the recording too, so ``p3at review FILE.rrd`` summarises
it. The warnings (what the command prints) are also WARN text under the map, and when the map's frame rests on a
sighting nothing checks (``frame_reliability_unchecked``, :mod:`estimation.frame_reliability`) that sighting is drawn
in the 2-D map: a ring on the pose it was taken from and its ray to the landmark, from its time on. A chain's map
whose frame or path rests on a naming nothing checks (``untestable_namings``, :mod:`estimation.naming_reliability`)
has the stretch of path that naming's sightings were taken from drawn the same way, labelled with the name.

The run is logged after it finished (the filter runs in estimation, which knows nothing of Rerun), thinned to one
pose every ``POSE_INTERVAL_S`` of log time. A saved file is written beside its name and renamed over it when
complete: an interrupted run never leaves half a recording, nor replaces an earlier one.
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from estimation.dataset_slam import DatasetRun
from estimation.datasets import RangeBearingLog
from estimation.geometry import between

from .rerun_log import MissionLog
from .rerun_sink import open_recording
from .rerun_style import dataset_blueprint

POSE_INTERVAL_S = 0.2   # log time between logged poses: 5 Hz draws the paths smoothly and keeps the file small


def record_dataset_run(sink: str, run: DatasetRun, log: RangeBearingLog, robot: str,
                       warnings: Sequence[str] = ()) -> None:
    """Log ``run`` (of ``log``, robot name ``robot``) to ``sink``: a path ending in .rrd, "spawn" or a rerun+http
    URL (see :func:`runtime.rerun_sink.open_recording`). A map whose metadata gives ``footprint_radius_m`` (MRCLAM's
    iRobot Creates) draws its robot as that disc, not as the P3-AT's box. ``warnings``: the run's, one line each,
    logged at the log's end."""
    saved = sink.endswith(".rrd")
    target = Path(sink)
    partial = target.with_name(f".{target.name}.{os.getpid()}.partial") if saved else None
    blueprint = dataset_blueprint(robot, smoothed=bool(run.metrics.get("smoothed")),
                                  scored="true_start_pose" in run.metrics, truth_heading=log.truth_heading,
                                  warned=bool(warnings))
    # written at once after the run, so the footer (an index of every chunk) costs nothing here: the file is then
    # complete for `rerun rrd verify` and random access (a mission leaves it out, open_recording)
    rec = open_recording(str(partial) if saved else sink, blueprint=blueprint, footer=saved)
    mission = MissionLog(rec, [robot], blueprint=False)
    try:
        _log_run(mission, run, log, robot, warnings)
        mission.close()
        if partial is not None:
            os.replace(partial, target)
    finally:
        mission.close()
        if partial is not None:
            partial.unlink(missing_ok=True)


def _log_run(mission: MissionLog, run: DatasetRun, log: RangeBearingLog, robot: str, warnings: Sequence[str]
             ) -> None:
    # a log without ground truth: the map's frame placed at the world's origin, no true path or landmarks
    scored = "true_start_pose" in run.metrics
    start = np.asarray(run.metrics["true_start_pose"], float) if scored else np.zeros(3)
    t0 = float(run.metrics["start_time"])
    mission.log_robot_frame(robot, start)
    if "footprint_radius_m" in run.map.metadata:
        mission.log_disc_body(robot, float(run.map.metadata["footprint_radius_m"]))
    if len(log.truth_ids) and scored:
        true_landmarks = between(start, np.column_stack([log.truth_positions, np.zeros(len(log.truth_ids))]))
        mission.log_true_landmarks(robot, true_landmarks[:, :2], labels=log.truth_ids.tolist())
    estimated = between(start, run.estimated_trajectory[:, 1:])
    true = between(start, run.true_trajectory[:, 1:]) if scored else [None] * len(run.estimated_trajectory)
    dead = between(start, run.dead_reckoning[:, 1:])
    times = run.estimated_trajectory[:, 0] - t0
    last = last_nees = -np.inf
    for k, t in enumerate(times):
        # the NEES where there is one (a smoothed run has it at every tenth frame), on its own clock
        if np.isfinite(run.pose_nees[k]) and t - last_nees >= POSE_INTERVAL_S:
            last_nees = t
            mission.log_scalars(robot, float(t), {"pose_nees": float(run.pose_nees[k])})
        if t - last < POSE_INTERVAL_S and k != len(times) - 1:
            continue
        last = t
        mission.log_pose(robot, float(t), None, estimated[k], true=true[k], odometry=dead[k])
    end = float(times[-1]) if len(times) else 0.0
    _log_frame_tie(mission, run, robot, estimated, t0)
    _log_naming_ties(mission, run, robot, estimated, t0)
    for warning in warnings:
        mission.log_event(end, warning, level="WARN")
    mission.log_robot_landmarks(robot, end, None, run.map)
    mission.log_map(robot, end, run.map)
    mission.log_summary({key: value for key, value in run.metrics.items() if np.isscalar(value)}
                        | {"robot": robot, "warnings": list(warnings)})


def _log_frame_tie(mission: MissionLog, run: DatasetRun, robot: str, estimated: np.ndarray, t0: float) -> None:
    """The sighting the warning names (the heading's worst if the heading is unchecked, else the translation's, as
    :func:`estimation.frame_reliability.reliability_warning` picks), on the estimated pose nearest its time."""
    m = run.metrics
    if not m.get("frame_reliability_unchecked") or not len(estimated):
        return
    heading = m["frame_reliability_effect_sd"][2] > m["frame_reliability_delta0"]
    sighting = m["frame_reliability_heading_sighting" if heading else "frame_reliability_translation_sighting"]
    k = int(np.argmin(np.abs(run.estimated_trajectory[:, 0] - sighting["time_s"])))
    identity = sighting.get("landmark", sighting.get("name"))
    external = [int(i) for i in run.map.metadata.get("external_ids", [])]
    landmark = run.map.positions[external.index(identity)] if identity in external else None
    which = "landmark" if "landmark" in sighting else "name"
    label = (f"the frame rests on this {sighting['component']} ({which} {identity}, "
             f"{max(m['frame_reliability_effect_sd']):.1f} σ)")
    mission.log_frame_tie(robot, float(run.estimated_trajectory[k, 0] - t0), estimated[k], landmark, label)


MAX_NAMING_TIES = 5   # the worst first: more would hide the map under them (the JSON has them all)


def _log_naming_ties(mission: MissionLog, run: DatasetRun, robot: str, estimated: np.ndarray, t0: float) -> None:
    """Each unchecked naming's run (``untestable_namings``, worst first, at most MAX_NAMING_TIES): the estimated path
    between its first and last sighting."""
    times = run.estimated_trajectory[:, 0]
    for k, naming in enumerate(run.metrics.get("untestable_namings") or []):
        if k == MAX_NAMING_TIES or not len(times):
            return
        seen = np.flatnonzero((times >= naming["start_s"]) & (times <= naming["end_s"]))
        if not len(seen):
            continue
        # None: the frame's move is unbounded (the stretch the run ties floats without it)
        effects = naming["frame_effect_sd"]
        moved = "the frame floats without it" if None in effects else f"{max(effects):.1f} σ of the frame"
        label = (f"these {naming['sightings']} sightings ({naming['start_s']:.2f}-{naming['end_s']:.2f} s) named "
                 f"{naming['name']}: the map rests on that naming and nothing checks it ({moved})")
        mission.log_naming_tie(robot, str(k), float(times[seen[0]] - t0), estimated[seen, :2], label)
