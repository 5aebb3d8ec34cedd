"""Shared by the Rerun tests: a small mission logged through every MissionLog method, and what a recording holds."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from estimation.fastslam.config import FastSLAMConfig
from estimation.fastslam.self_check import SelfCheck
from estimation.landmark_map import LandmarkMap
from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording
from runtime.rerun_style import mission_blueprint

ROBOTS = ["robot1", "robot2"]
TWO_D = ("Points2D:", "LineStrips2D:", "Arrows2D:", "Boxes2D:", "EncodedImage:", "Image:", "DepthImage:")


def landmark_map(robot: str, n: int, rng: np.random.Generator, counts=None, trajectory_len: int = 20,
                 robots=None, seen_by=None) -> LandmarkMap:
    a = rng.normal(size=(n, 3, 3)) * 0.1
    t = np.arange(trajectory_len, dtype=float)
    return LandmarkMap(rng.uniform(-5, 5, (n, 3)), a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(3),
                       rng.normal(size=(n, 8)).astype(np.float32), np.arange(n),
                       counts if counts is not None else np.full(n, 5), robot, "start", robots, seen_by,
                       np.column_stack([t, 0.1 * t, 0.05 * t, np.zeros_like(t)]))


def footed_recording(rrd: Path, frames: int):
    """A finished small mission saved to ``rrd`` with Rerun's footer (``footer=True``, as files written before the
    footer was turned off), each frame written before the next; returns (rrd, what read_recording finds in it)."""
    log = MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS), footer=True), ROBOTS,
                     blueprint=False)
    log_small_mission(log, frames=frames, flush_each_frame=True)
    log.close()
    return rrd, read_recording(rrd)


def log_small_mission(log, frames: int = 12, seed: int = 0, flush_each_frame: bool = False) -> dict:
    """Every kind of thing the runtime logs, for two robots and a fusion. Returns what was logged that a test
    checks against. ``flush_each_frame``: write each frame before the next (the file then holds them in time order,
    as a mission slower than Rerun's batching does; a test this fast would otherwise write them all at once)."""
    rng = np.random.default_rng(seed)
    log.log_building(np.array([[-1.0, -2.0, 10.0, -2.0], [-1.0, 2.0, 10.0, 2.0]]), np.array([2.5, 2.5]))
    starts = {"robot1": np.zeros(3), "robot2": np.array([8.0, 0.0, np.pi])}
    for name in ROBOTS:
        log.log_robot_frame(name, starts[name])
        log.log_camera_model(name, 520, 520, 31.5, 23.5, 64, 48, 0.09)
    log.log_robot_frame("fused", starts["robot1"])
    local = None
    for frame in range(frames):
        t = 0.25 * frame
        for name in ROBOTS:
            pose = np.array([0.1 * frame, 0.01 * frame, 0.0])
            log.log_pose(name, t, frame, pose, pose + 0.01, (0.12, 0.045, 0.5), odometry=pose * 1.1)
            log.log_particles(name, t, frame, pose + rng.normal(0, 0.05, (20, 3)))
            log.log_scalars(name, t, {"ess": 80.0, "landmarks/all": 10 + frame, "observations": 30,
                                      "dropped": 0, "time/frontend": 5.0, "time/predict": 0.5,
                                      "time/update": 9.0}, frame)
            log.log_stereo(name, t, frame, rng.integers(0, 255, (48, 64), np.uint8),
                           rng.integers(0, 255, (48, 64), np.uint8), rng.uniform(0, 40, (5, 2)),
                           rng.uniform(0, 40, (5, 2)))
            log.log_sonar(name, t, pose, np.array([[0.1, 0.0, 0.0], [0.1, 0.1, 1.0]]), np.array([2.0, 3.0]))
            if frame % 4 == 0:
                local = landmark_map(name, 12, rng, counts=np.array([1, 2] * 3 + [3, 4, 5, 6, 7, 8]))
                log.log_robot_landmarks(name, t, frame, local, confirm_count=3)
        if flush_each_frame:
            log.flush()
    t = 0.25 * frames
    snapshots = {name: landmark_map(name, 8, rng) for name in ROBOTS}
    for name, m in snapshots.items():
        m.metadata = {"self_check": SelfCheck(FastSLAMConfig()).verdict()}   # what FastSLAM.best_map carries
        log.log_map(name, t, m)
    log.log_alignment(t, "robot1", "robot2", {"reference": "robot1", "other": "robot2", "aligned": True,
                                              "tx": 8.0, "ty": 0.0, "theta": np.pi, "supports": 20, "common": 6,
                                              "error_xy": 0.05, "error_theta": 0.01, "merged": 10})
    seen = np.zeros((10, 2), bool)
    seen[:4, 0] = True
    seen[4:8, 1] = True
    seen[8:, :] = True
    fused = landmark_map("robot1", 10, rng, robots=ROBOTS, seen_by=seen)
    log.log_map("fused", t, fused)
    log.log_event(t, "done")
    log.log_summary({"robots": {}})
    return {"snapshots": snapshots, "fused": fused, "local": local, "duration": t}


def entity_columns(rrd: Path) -> dict[str, set[str]]:
    """entity path (no leading '/') -> the component columns ("Archetype:field") it holds in the recording."""
    import rerun.chunk as rrchunk

    columns: dict[str, set[str]] = {}
    for chunk in rrchunk.RrdReader(rrd).stream():
        names = {n for n in chunk.to_record_batch().schema.names if ":" in n}
        columns.setdefault(chunk.entity_path.lstrip("/"), set()).update(names)
    return columns


def entity_rows(rrd: Path, entity: str) -> list[dict]:
    """Every row logged at ``entity``, as plain Python values (ordered as stored)."""
    import rerun.chunk as rrchunk

    rows = []
    for chunk in rrchunk.RrdReader(rrd).stream().filter(content=[f"+ /{entity}"]):
        batch = chunk.to_record_batch()
        data = {k: batch.column(k).to_pylist() for k in batch.schema.names}
        rows.extend({k: v[i] for k, v in data.items()} for i in range(chunk.num_rows))
    return rows


def viewer_state(rrd: Path, timeline: str, times) -> dict[str, dict[int, dict]]:
    """What a viewer shows of each entity at each of ``times`` on ``timeline`` (``frame``: sequence numbers;
    ``sim_time``: nanoseconds): entity -> time -> {component column ("Archetype:field"): value}.

    Each component resolved as Rerun's viewer does (its data model, "Query semantics" and "Static data"): a static
    value shadows every temporal one; otherwise the value of the newest row at or before the time that holds the
    component (ties broken by row id, the order of logging). Rows that lack the timeline are not on it. An entity
    with temporal rows is left out of the times before its first one (its static style alone draws nothing); an
    entity with static data only is at every time. Only the recording is read, not the blueprint."""
    import bisect

    import rerun.chunk as rrchunk

    reader = rrchunk.RrdReader(rrd)
    static: dict[str, dict[str, tuple[bytes, object]]] = {}
    temporal: dict[str, dict[str, list[tuple[int, bytes, object]]]] = {}
    for store in reader.recordings():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            names = batch.schema.names
            entity = chunk.entity_path.lstrip("/")
            row_ids = batch.column("rerun.controls.RowId").to_pylist()
            components = [n for n in names if ":" in n]
            if chunk.is_static:
                held = static.setdefault(entity, {})
                for name in components:
                    for row_id, value in zip(row_ids, batch.column(name).to_pylist(), strict=True):
                        if value is not None and (name not in held or held[name][0] < row_id):
                            held[name] = (row_id, value)
            elif timeline in names:
                stamps = batch.column(timeline).cast("int64").to_pylist()
                held = temporal.setdefault(entity, {})
                for name in components:
                    for stamp, row_id, value in zip(stamps, row_ids, batch.column(name).to_pylist(), strict=True):
                        if value is not None and stamp is not None:
                            held.setdefault(name, []).append((stamp, row_id, value))
    state: dict[str, dict[int, dict]] = {}
    for entity in sorted(set(static) | set(temporal)):
        columns = {name: sorted(rows, key=lambda r: (r[0], r[1])) for name, rows in temporal.get(entity, {}).items()}
        stamps = {name: [r[0] for r in rows] for name, rows in columns.items()}
        fixed = {name: value for name, (_, value) in static.get(entity, {}).items()}
        for t in times:
            seen = {}
            for name, rows in columns.items():
                k = bisect.bisect_right(stamps[name], t)
                if k:
                    seen[name] = rows[k - 1][2]
            # an entity with temporal rows shows nothing before its first one (its static style alone draws nothing)
            if seen or not columns:
                state.setdefault(entity, {})[t] = {**seen, **fixed}
    return state


def blueprint_views(node):
    """Every view of a blueprint (or container), depth first."""
    if hasattr(node, "class_identifier"):
        yield node
        return
    for child in getattr(node, "contents", None) or []:
        yield from blueprint_views(child)
