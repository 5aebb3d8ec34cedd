"""What a viewer shows of the per-frame entities (poses, paths, particles) is each frame's whole archetype, although
the logger sends the styling once per entity (static) and then only the data: read the file back, resolve every
component at each frame as Rerun's viewer does (static shadows temporal, else latest-at), compare with the archetype
built whole from the same inputs."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.rerun_log import MissionLog
from runtime.rerun_rows import HELD_ROWS_MAX
from runtime.rerun_sdk import rr
from runtime.rerun_sink import open_recording
from runtime.rerun_style import TRUE_COLOUR, robot_colour

from .rerun_helpers import viewer_state

ROBOT = "robot2"
FRAMES = 6
HELD_FRAMES = HELD_ROWS_MAX + 8   # past the rows an entity holds at most: sent in several columns


def _poses(frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    estimated = np.array([0.3 * frame, 0.05 * frame, 0.2 * frame - 0.4])
    rng = np.random.default_rng(frame)
    return estimated, estimated + [0.02, -0.01, 0.03], estimated * 1.05, estimated + rng.normal(0, 0.1, (25, 3))


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    rrd = tmp_path_factory.mktemp("per_frame") / "m.rrd"
    log = MissionLog(open_recording(str(rrd)), [ROBOT], blueprint=False)
    for frame in range(FRAMES):
        estimated, true, odometry, particles = _poses(frame)
        log.log_pose(ROBOT, 0.25 * frame, frame, estimated, true, (0.12, 0.045, 0.5), odometry=odometry)
        log.log_particles(ROBOT, 0.25 * frame, frame, particles)
    log.close()
    return rrd, viewer_state(rrd, "frame", range(FRAMES))


def _components(archetype) -> dict:
    return {batch.component_descriptor().component: batch.as_arrow_array().to_pylist()
            for batch in archetype.as_component_batches()}


def _whole_archetypes(frame: int) -> dict:
    """Each per-frame entity's archetype at ``frame``, built whole (styling and data in one call) from the inputs."""
    colour = robot_colour(ROBOT)
    dim = tuple(int(0.45 * c + 0.55 * 30) for c in colour)
    estimated, true, odometry, particles = _poses(frame)

    def arrow(pose, z=0.0):
        return {"origins": [[pose[0], pose[1], z]], "vectors": [[0.5 * np.cos(pose[2]), 0.5 * np.sin(pose[2]), 0.0]]}

    def path(poses_of, z=None):
        points = np.array([poses_of(k)[:2] for k in range(frame + 1)])
        return points if z is None else np.column_stack([points, np.full(len(points), z)])

    return {
        f"world/{ROBOT}/pose": rr.Arrows3D(**arrow(estimated), colors=colour, radii=0.03),
        f"world/{ROBOT}/true_pose": rr.Arrows3D(**arrow(true), colors=TRUE_COLOUR, radii=0.02),
        f"world/{ROBOT}/trajectory/0000": rr.LineStrips3D([path(lambda k: _poses(k)[0], 0.02)], colors=colour,
                                                          radii=0.02),
        f"world/{ROBOT}/true_trajectory/0000": rr.LineStrips3D([path(lambda k: _poses(k)[1], 0.01)],
                                                               colors=TRUE_COLOUR, radii=0.01),
        f"world/{ROBOT}/particles": rr.Points3D(np.column_stack([particles[:, :2], np.full(len(particles), 0.03)]),
                                                radii=0.015, colors=colour),
        f"map/{ROBOT}/trajectory/estimated/0000": rr.LineStrips2D([path(lambda k: _poses(k)[0])], colors=colour,
                                                                  radii=-2.0, draw_order=3.0),
        f"map/{ROBOT}/trajectory/odometry/0000": rr.LineStrips2D([path(lambda k: _poses(k)[2])], colors=dim,
                                                                 radii=-1.5, draw_order=2.0),
        f"map/{ROBOT}/trajectory/true/0000": rr.LineStrips2D([path(lambda k: _poses(k)[1])], colors=TRUE_COLOUR,
                                                             radii=-1.0, draw_order=1.0),
        f"map/{ROBOT}/pose": rr.Points2D([estimated[:2]], radii=-7.0, colors=colour, labels=[ROBOT],
                                         show_labels=True, draw_order=10.0),
        f"map/{ROBOT}/pose/heading": rr.Arrows2D(vectors=[0.6 * np.array([np.cos(estimated[2]),
                                                                           np.sin(estimated[2])])],
                                                 origins=[estimated[:2]], radii=-2.0, colors=colour,
                                                 draw_order=10.0),
        f"map/{ROBOT}/true_pose": rr.Points2D([true[:2]], radii=-4.0, colors=TRUE_COLOUR, draw_order=9.0),
        f"map/{ROBOT}/particles": rr.Points2D(particles[:, :2], radii=-1.5, colors=dim, draw_order=8.0),
    }


@pytest.mark.parametrize("frame", [0, 1, FRAMES - 1])
def test_each_frame_shows_the_whole_archetype_of_every_per_frame_entity(logged, frame):
    _, state = logged
    for entity, archetype in _whole_archetypes(frame).items():
        assert state[entity][frame] == _components(archetype), entity


def test_the_base_link_and_the_head_are_placed_on_the_estimated_pose(logged):
    _, state = logged
    estimated = _poses(3)[0]
    base = state[f"world/{ROBOT}/base_link"][3]
    np.testing.assert_allclose(base["Transform3D:translation"], [[estimated[0], estimated[1], 0.0]], atol=1e-6)
    np.testing.assert_allclose(base["Transform3D:quaternion"],
                               [[0.0, 0.0, np.sin(estimated[2] / 2), np.cos(estimated[2] / 2)]], atol=1e-6)
    head = state[f"world/{ROBOT}/stereo"][3]
    c, s = np.cos(estimated[2]), np.sin(estimated[2])
    np.testing.assert_allclose(head["Transform3D:translation"], [[estimated[0] + 0.12 * c - 0.045 * s,
                                                                  estimated[1] + 0.12 * s + 0.045 * c, 0.5]],
                               atol=1e-6)


def test_the_style_is_sent_once_per_entity_and_each_frame_sends_only_its_data(logged):
    """What makes a frame cheaper: a row per frame with the data alone (Rerun's cost is about per array sent)."""
    import rerun.chunk as rrchunk

    rrd, _ = logged
    rows: dict[tuple[str, bool], list[set[str]]] = {}
    for chunk in rrchunk.RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        entity = chunk.entity_path.lstrip("/")
        columns = [n for n in batch.schema.names if ":" in n]
        for i in range(chunk.num_rows):
            rows.setdefault((entity, chunk.is_static), []).append(
                {n for n in columns if batch.column(n)[i].is_valid})
    per_frame = rows[(f"map/{ROBOT}/pose", False)]
    assert len(per_frame) == FRAMES and all(r == {"Points2D:positions"} for r in per_frame)
    assert rows[(f"map/{ROBOT}/pose", True)] == [{"Points2D:radii", "Points2D:colors", "Points2D:labels",
                                                  "Points2D:show_labels", "Points2D:draw_order"}]
    assert all(r == {"Points3D:positions"} for r in rows[(f"world/{ROBOT}/particles", False)])


def _rows(rrd) -> dict[str, list]:
    """entity -> its temporal rows as (sim_time, frame, whether log_time is set, {component: value}), sorted."""
    import rerun.chunk as rrchunk

    reader = rrchunk.RrdReader(rrd)
    found: dict[str, list] = {}
    for store in reader.recordings():
        for chunk in reader.stream(store=store):
            if chunk.is_static:
                continue
            batch = chunk.to_record_batch()
            data = {k: batch.column(k).to_pylist() for k in batch.schema.names}
            for i in range(chunk.num_rows):
                found.setdefault(chunk.entity_path.lstrip("/"), []).append((
                    data["sim_time"][i], data.get("frame", [None] * chunk.num_rows)[i],
                    data.get("log_time", [None] * chunk.num_rows)[i] is not None,
                    {k: v[i] for k, v in data.items() if ":" in k and v[i] is not None}))
    return {entity: sorted(rows, key=repr) for entity, rows in found.items()}


def _mission(log: MissionLog, frames: int) -> None:
    """Per-frame logging with and without frame numbers (a data set's poses carry none), a self-check series
    logged without one, and a flush halfway."""
    for frame in range(frames):
        estimated, true, odometry, particles = _poses(frame)
        numbered = frame if frame % 4 else None
        log.log_pose(ROBOT, 0.25 * frame, numbered, estimated, true, (0.12, 0.045, 0.5), odometry=odometry)
        log.log_particles(ROBOT, 0.25 * frame, numbered, particles)
        log.log_scalars(ROBOT, 0.25 * frame, {"ess": 50.0 + frame, "time/update": 0.5 * frame}, numbered)
        if frame % 3 == 0:
            log.log_scalars(ROBOT, 0.25 * frame, {"self_check": 0.1 * frame})
        if frame == frames // 2:
            log.flush()


def test_rows_held_for_a_saved_file_are_the_rows_a_live_stream_gets(tmp_path):
    """A saved file holds each entity's per-frame rows and sends them as columns: the same rows, at the same times
    (sim_time, frame, log_time), with the same values, and the same view at every frame, as logged one by one."""
    held, live = tmp_path / "held.rrd", tmp_path / "live.rrd"
    for rrd, hold in ((held, None), (live, False)):
        log = MissionLog(open_recording(str(rrd)), [ROBOT], blueprint=False, hold_rows=hold)
        assert log.hold_rows == (hold is None)  # None: a file open_recording saves is held
        _mission(log, HELD_FRAMES)
        log.close()
    rows = _rows(held)
    assert rows == _rows(live)
    assert len(rows[f"map/{ROBOT}/pose"]) == HELD_FRAMES
    assert len(rows[f"plots/{ROBOT}/self_check"]) == (HELD_FRAMES + 2) // 3
    for timeline, times in (("frame", range(HELD_FRAMES)),
                            ("sim_time", [250_000_000 * k for k in range(HELD_FRAMES)])):
        shown, expected = viewer_state(held, timeline, times), viewer_state(live, timeline, times)
        shown.pop("__properties"), expected.pop("__properties")   # Rerun's own: the recording's start time
        assert shown == expected


def test_held_rows_are_in_the_file_once_flushed_and_a_live_stream_holds_none(tmp_path):
    rrd = tmp_path / "m.rrd"
    log = MissionLog(open_recording(str(rrd)), [ROBOT], blueprint=False)
    _mission(log, 3)
    log.flush()
    assert len(_rows(rrd)[f"world/{ROBOT}/base_link"]) == 3   # read while the stream is still open
    log.close()
    assert not MissionLog(open_recording("memory"), [ROBOT]).hold_rows


def test_a_logger_never_closed_still_writes_its_held_rows_at_exit(tmp_path):
    """A script that forgets ``close()``: Rerun flushes its own buffers at exit, and the rows held for the file are
    sent before that."""
    import subprocess
    import sys
    from pathlib import Path

    rrd = tmp_path / "m.rrd"
    script = ("import numpy as np\n"
              "from runtime.rerun_log import MissionLog\n"
              "from runtime.rerun_sink import open_recording\n"
              f"log = MissionLog(open_recording({str(rrd)!r}), ['robot2'], blueprint=False)\n"
              "for frame in range(5):\n"
              "    log.log_pose('robot2', 0.25 * frame, frame, np.array([0.1 * frame, 0.0, 0.0]))\n")
    root = Path(__file__).resolve().parents[2]
    subprocess.run([sys.executable, "-c", script], check=True, cwd=root, timeout=120)
    assert len(_rows(rrd)[f"world/{ROBOT}/base_link"]) == 5
