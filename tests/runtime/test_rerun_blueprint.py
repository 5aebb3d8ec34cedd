"""The recording's layout against what it holds: walk the blueprint object that mission_blueprint builds, match each
view's contents against the entities of a real recording, and check what a reader would see (no 2-D entity in a
3-D view without a pinhole, one quantity per plot with units and distinct colours, maps drawn y up)."""
from __future__ import annotations

import re
import sys
from collections import deque

import numpy as np
import pytest

from runtime.rerun_log import TRAJECTORY_SEGMENT, MissionLog, landmark_confirmed
from runtime.rerun_sink import open_recording
from runtime.rerun_style import SERIES, mission_blueprint, robot_colour

from .rerun_helpers import ROBOTS, TWO_D, blueprint_views, entity_columns, entity_rows, landmark_map, log_small_mission


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rrd = tmp_path_factory.mktemp("rec") / "m.rrd"
    log = MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS)), ROBOTS, blueprint=False)
    logged = log_small_mission(log)
    log.close()
    return rrd, logged, entity_columns(rrd)


def _included(view, entity: str) -> bool:
    """Does ``entity`` fall in the view's contents? (Rerun's entity-path filter: '+'/'-' rules, '/**' subtrees,
    '$origin' substitution; an exclusion wins.)"""
    rules = view.contents if isinstance(view.contents, list) else [view.contents]
    verdict = False
    for rule in rules:
        rule = str(rule).strip()
        sign, pattern = ("-", rule[1:].strip()) if rule.startswith("-") else ("+", rule.lstrip("+").strip())
        pattern = pattern.replace("$origin", str(view.origin)).strip("/")
        if pattern.endswith("/**"):
            base = pattern[:-3]
            hit = entity == base or entity.startswith(base + "/") or base == ""
        elif pattern == "**":
            hit = True
        else:
            hit = entity == pattern
        if hit and sign == "-":
            return False
        verdict = verdict or hit
    return verdict


def _views(kind: str):
    return [v for v in blueprint_views(mission_blueprint(ROBOTS).root_container) if v.class_identifier == kind]


def _is_2d(columns: set[str]) -> bool:
    return any(c.startswith(TWO_D) for c in columns)


def test_the_tabs_are_an_overview_each_robot_the_fusion_and_the_3d_world():
    tabs = mission_blueprint(ROBOTS).root_container
    assert [t.name for t in tabs.contents] == ["overview", *ROBOTS, "fusion", "3-D", "summary"]
    assert tabs.active_tab in (0, "overview")


def test_each_view_has_one_place_in_the_layout():
    """A view object placed twice shares one id: the viewer shows it in one place and leaves the other black."""
    ids = [view.id for view in blueprint_views(mission_blueprint(ROBOTS).root_container)]
    assert len(ids) == len(set(ids))


def test_no_2d_entity_sits_in_a_3d_view_without_a_pinhole_ancestor(recording):
    _, _, columns = recording
    pinholes = {e for e, c in columns.items() if any(n.startswith("Pinhole:") for n in c)}
    (world,) = _views("3D")
    shown_2d = [e for e, c in columns.items() if _is_2d(c) and _included(world, e)]
    assert shown_2d, "the 3-D view should show the camera images under their pinholes"
    for entity in shown_2d:
        parts = entity.split("/")
        ancestors = {"/".join(parts[:i]) for i in range(1, len(parts) + 1)}
        assert ancestors & pinholes, f"{entity} is 2-D, in the 3-D view, with no pinhole above it"
    # the side-by-side pair (no pinhole) lives outside the 3-D world
    assert not any(_included(world, e) for e in columns if e.startswith("images/"))


def test_every_2d_view_shows_2d_data_and_the_maps_hold_what_a_reader_needs(recording):
    _, _, columns = recording
    for view in _views("2D"):
        shown = [e for e, c in columns.items() if _included(view, e) and _is_2d(c)]
        assert shown, f"2-D view '{view.name}' ({view.origin}, {view.contents}) shows nothing"
    for robot in ROBOTS:
        (local,) = {v.name: v for v in _views("2D") if v.contents == [f"+ map/{robot}/**"]}.values()
        wanted = {f"map/{robot}/{p}" for p in ("building", "pose", "particles", "landmarks/confirmed",
                                                "landmarks/provisional", "trajectory/estimated/0000",
                                                "trajectory/odometry/0000", "trajectory/true/0000")}
        assert wanted <= {e for e in columns if _included(local, e)}
    fused_entities = {e for e in columns if e.startswith("map/fused/")}
    assert {"map/fused/landmarks", "map/fused/building", "map/fused/robot2/trajectory"} <= fused_entities


def test_the_maps_are_drawn_y_up(recording):
    rrd, _, columns = recording
    for key in (*ROBOTS, "fused"):
        rows = entity_rows(rrd, f"map/{key}")
        matrices = [r[c] for r in rows for c in r if c.startswith("Transform3D:mat3x3") and r[c] is not None]
        assert matrices, f"map/{key} has no flip"
        flip = np.asarray(matrices[-1], float).reshape(-1)[:9].reshape(3, 3)
        # stored column-major or row-major: a diagonal matrix reads the same
        np.testing.assert_allclose(flip, np.diag([1.0, -1.0, 1.0]))


def test_each_plot_shows_one_quantity_with_its_unit_in_distinct_colours(recording):
    rrd, _, columns = recording
    series = {e: c for e, c in columns.items() if any(n.startswith("Scalars:") for n in c)}
    unit_group = {"ess": "ess", "observations": "count/frame", "dropped": "frames", "error_xy": "m",
                  "error_theta": "rad", "common": "landmarks", "merged": "landmarks",
                  "self_check": "log-likelihood ratio", "self_check/threshold": "log-likelihood ratio"}
    for view in _views("TimeSeries"):
        shown = [e for e in series if _included(view, e)]
        assert shown, f"plot '{view.name}' shows nothing"
        groups = set()
        for entity in shown:
            name = entity.split("/", 2)[2]
            groups.add("ms" if name.startswith("time/") else "landmarks" if name.startswith("landmarks/")
                       else unit_group[name])
        assert len(groups) == 1, f"plot '{view.name}' mixes {groups} on one axis"
        styles = []
        for entity in shown:
            rows = [r for r in entity_rows(rrd, entity) if r.get("SeriesLines:names") is not None]
            assert rows, f"{entity} has no legend name"
            styles.append((rows[-1]["SeriesLines:names"][0], tuple(rows[-1]["SeriesLines:colors"])))
        names, colours = zip(*styles, strict=True)
        assert len(set(colours)) == len(colours), f"plot '{view.name}' repeats a colour: {styles}"
        assert len(set(names)) == len(names)
    # units and what the counts count, in the legend names
    assert SERIES["error_xy"][0] == "error xy (m)" and SERIES["error_theta"][0] == "error θ (rad)"
    assert all(re.search(r"\(ms\)$", SERIES[k][0]) for k in SERIES if k.startswith("time/"))
    assert "confirmed, best particle" in SERIES["landmarks/confirmed"][0]
    assert "provisional" in SERIES["landmarks/provisional"][0]


def test_the_robots_covariance_ellipsoids_are_hidden_by_default_and_the_fused_ones_shown(recording):
    _, _, columns = recording
    (world,) = _views("3D")
    hidden = {str(path) for path, behaviour in world.visualizer_overrides.items()
              if "visible=[False]" in repr(behaviour)}
    covariances = {e for e, c in columns.items() if any(n.startswith("Ellipsoids3D:") for n in c)}
    assert covariances == {"world/robot1/landmarks/covariance", "world/robot2/landmarks/covariance",
                           "world/fused/landmarks/covariance"}
    assert hidden == covariances - {"world/fused/landmarks/covariance"}


def test_landmarks_are_split_by_state_and_counted(recording):
    rrd, logged, _ = recording
    local = logged["local"]
    confirmed = landmark_confirmed(local, 3)
    np.testing.assert_array_equal(confirmed, local.counts >= 3)
    rows = [r for r in entity_rows(rrd, "map/robot2/landmarks/confirmed") if r.get("Points2D:positions")]
    np.testing.assert_allclose(np.array(rows[-1]["Points2D:positions"]), local.positions[confirmed, :2], atol=1e-6)
    counts = [r["Scalars:scalars"] for r in entity_rows(rrd, "plots/robot2/landmarks/provisional")
              if r.get("Scalars:scalars") is not None]
    assert counts[-1] == [float((~confirmed).sum())]


def test_landmark_state_uses_an_existence_probability_when_the_map_has_one_and_ignores_a_bad_one():
    rng = np.random.default_rng(1)
    m = landmark_map("robot1", 4, rng, counts=np.array([5, 5, 1, 5]))
    assert landmark_confirmed(m).tolist() == [True, True, False, True]  # FastSLAM's default confirm_count
    m.existence = np.array([0.9, 0.2, 0.9, 0.5])
    assert landmark_confirmed(m).tolist() == [True, False, False, True]
    for bad in (np.array([0.9, 0.2]), np.array([3.0, -2.0, 1.0, 0.0]), "nonsense"):
        m.existence = bad
        assert landmark_confirmed(m).tolist() == [True, True, False, True]


def test_fused_landmarks_take_the_colour_of_the_robot_that_saw_them_white_when_several_did(recording):
    rrd, logged, _ = recording
    rows = [r for r in entity_rows(rrd, "map/fused/landmarks") if r.get("Points2D:colors")]
    colours = [tuple(int(c).to_bytes(4, "big")[:3]) for c in rows[-1]["Points2D:colors"]]
    seen = logged["fused"].seen_by
    for colour, row in zip(colours, seen, strict=True):
        expected = (255, 255, 255) if row.sum() > 1 else robot_colour(ROBOTS[int(np.argmax(row))])
        assert colour == expected


def test_robot_colours_do_not_depend_on_who_logs_them():
    """A fleet's processes each log their own robot: robot2 must have robot2's colour in all of them."""
    assert robot_colour("robot2") == MissionLog(open_recording("none"), ["robot2"]).colour("robot2")
    assert len({robot_colour(f"robot{i}") for i in range(1, 7)}) == 6


def _retained_bytes(value, seen: set[int] | None = None) -> int:
    """Bytes a Python object keeps reachable: containers, arrays and plain objects walked (the Rerun stream is not)."""
    seen = set() if seen is None else seen
    if id(value) in seen or isinstance(value, type) or callable(value):
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        return sys.getsizeof(value) + (value.nbytes if value.base is None else 0)
    size = sys.getsizeof(value)
    if isinstance(value, dict):
        size += sum(_retained_bytes(k, seen) + _retained_bytes(v, seen) for k, v in value.items())
    elif isinstance(value, list | tuple | set | frozenset | deque):
        size += sum(_retained_bytes(v, seen) for v in value)
    elif hasattr(value, "__dict__") and type(value).__module__.startswith("runtime"):
        size += _retained_bytes(vars(value), seen)
    return size


@pytest.mark.slow
def test_the_logger_keeps_no_more_state_in_a_long_mission_than_in_a_short_one(tmp_path):
    """What MissionLog holds between calls is bounded: the open trajectory segment, one style per series, one
    snapshot path per robot. Measured by walking what the logger object keeps reachable (Rerun's own buffers are
    Rust-side: bounded by its batcher and the file sink, which writes as it goes). tracemalloc is not used: with
    Rerun's native threads freeing buffers it crashed the interpreter in rerun-sdk 0.41 (a full suite, twice)."""

    def run(frames: int) -> int:
        log = MissionLog(open_recording(str(tmp_path / f"{frames}.rrd")), ["robot1"], blueprint=False)
        for frame in range(frames):
            pose = np.array([0.01 * frame, 0.0, 0.0])
            log.log_pose("robot1", 0.1 * frame, frame, pose, pose, odometry=pose)
            log.log_scalars("robot1", 0.1 * frame, {"ess": 1.0, "time/update": 2.0}, frame)
        held = _retained_bytes({k: v for k, v in vars(log).items() if k != "rec"})
        log.close()
        return held

    short, long = run(TRAJECTORY_SEGMENT + 10), run(3 * TRAJECTORY_SEGMENT + 10)
    # keeping every pose would hold 2 more segments x 3 paths x 150 poses (> 20 kB even as float64 arrays)
    assert long < short + 4_000, (short, long)
