"""What a reviewer opening a recording sees, read back from the saved file as the viewer resolves it (session 49, V):
the fused map drawn in the frame its landmarks are in, in every process that logs it; and the fusion status before
the first fusion says so instead of an empty panel."""
from __future__ import annotations

import numpy as np

from estimation.geometry import between
from runtime.rerun_log import NO_FUSION_YET, MissionLog
from runtime.rerun_sink import open_recording
from runtime.rerun_style import FUSION_STATUS

from .rerun_helpers import ROBOTS, entity_rows, landmark_map, viewer_state

NS = 1_000_000_000
WALLS = np.array([[-3.0, -5.0, 32.0, -5.0], [-3.0, 5.0, 32.0, 5.0], [32.0, -5.0, 32.0, 5.0]])
STARTS = {"robot1": np.array([3.0, 5.0, 0.0]), "robot2": np.array([8.0, 5.0, np.pi])}


def _fused_map(rng):
    seen = np.zeros((6, 2), bool)
    seen[:3, 0] = seen[3:, 1] = True
    fused = landmark_map("robot1", 6, rng, robots=ROBOTS, seen_by=seen)
    fused.metadata = {"true_start_pose": STARTS["robot1"].tolist()}   # what a fused map of the mocks carries
    return fused


def test_a_fleet_robots_fused_map_is_drawn_in_the_reference_robots_frame(tmp_path):
    """robot2's own process of a fleet (runtime/mission.py with robot2 alone) places "fused" at its own start; the
    fused map it receives is in robot1's frame (fusion's reference) and says so (``true_start_pose``). Before: its
    3-D fused landmarks sat at robot2's start turned by π, and its 2-D fused map's walls were robot2's frame's."""
    rrd = tmp_path / "robot2.rrd"
    log = MissionLog(open_recording(str(rrd)), ["robot2"], blueprint=False)
    log.log_building(WALLS, np.full(len(WALLS), 2.5))
    log.log_robot_frame("robot2", STARTS["robot2"])
    log.log_robot_frame("fused", STARTS["robot2"])          # runtime/mission.py: its first robot's true start
    log.log_map("fused", 30.0, _fused_map(np.random.default_rng(1)))
    log.close()

    shown = viewer_state(rrd, "sim_time", [30 * NS])
    placed = shown["world/fused"][30 * NS]
    assert np.allclose(placed["Transform3D:translation"][0], [3.0, 5.0, 0.0])
    assert np.allclose(placed["Transform3D:quaternion"][0], [0.0, 0.0, 0.0, 1.0], atol=1e-9)
    ends = WALLS.reshape(-1, 2)
    expected = between(STARTS["robot1"], np.column_stack([ends, np.zeros(len(ends))]))[:, :2].reshape(-1, 2, 2)
    drawn = np.array(shown["map/fused/building"][30 * NS]["LineStrips2D:strips"], float)
    assert np.allclose(drawn, expected, atol=1e-5)
    # robot2's own map and frame are untouched
    assert np.allclose(shown["world/robot2"][30 * NS]["Transform3D:translation"][0], [8.0, 5.0, 0.0])


def test_a_fused_map_without_a_true_start_leaves_the_callers_placement(tmp_path):
    rrd = tmp_path / "node.rrd"
    log = MissionLog(open_recording(str(rrd)), ROBOTS, blueprint=False)
    log.log_robot_frame("fused", np.array([1.0, 2.0, 0.5]))
    fused = _fused_map(np.random.default_rng(2))
    fused.metadata = {"true_start_pose": None}               # a real robot's map: no truth
    log.log_map("fused", 20.0, fused)
    log.close()
    placed = viewer_state(rrd, "sim_time", [20 * NS])["world/fused"][20 * NS]
    assert np.allclose(placed["Transform3D:translation"][0], [1.0, 2.0, 0.0])


def test_the_fusion_status_before_the_first_fusion_says_there_is_none_yet(tmp_path):
    rrd = tmp_path / "mission.rrd"
    log = MissionLog(open_recording(str(rrd)), ROBOTS, blueprint=False)
    log.log_pose("robot1", 5.0, 10, np.zeros(3))
    log.log_alignment(20.0, "robot1", "robot2", {"aligned": False, "supports": 3, "required_supports": 9,
                                                 "note": "too few supports"})
    log.close()
    shown = viewer_state(rrd, "sim_time", [0, 10 * NS, 25 * NS])[FUSION_STATUS]
    assert str(shown[0]["TextDocument:text"][0]) == NO_FUSION_YET
    assert str(shown[10 * NS]["TextDocument:text"][0]) == NO_FUSION_YET
    assert "not aligned" in str(shown[25 * NS]["TextDocument:text"][0])
    (media,) = {str(r["TextDocument:media_type"][0]) for r in entity_rows(rrd, FUSION_STATUS)}
    assert media == "text/markdown"


def test_a_fusion_node_that_learns_its_robots_says_no_fusion_yet_and_keeps_its_own_time(tmp_path):
    """p3at fuse --live starts with no robot; the second robot's first map is when there is something to fuse."""
    rrd = tmp_path / "node.rrd"
    log = MissionLog(open_recording(str(rrd)), [])
    rng = np.random.default_rng(3)
    for robot in ROBOTS:
        log.log_map(robot, 7.5, landmark_map(robot, 5, rng))
    log.close()
    status = viewer_state(rrd, "sim_time", [0])[FUSION_STATUS][0]
    assert str(status["TextDocument:text"][0]) == NO_FUSION_YET
    # the map that brought the second robot is logged at its own time, not at the status's t = 0
    times = {r["sim_time"].value for r in entity_rows(rrd, "maps/robot2")}
    assert times == {int(7.5 * NS)}


def test_a_robots_own_process_logs_no_fusion_status(tmp_path):
    """A fleet's robot process logs one robot; the fusion node's status is the one a merged view shows."""
    rrd = tmp_path / "robot1.rrd"
    log = MissionLog(open_recording(str(rrd)), ["robot1"], blueprint=False)
    log.log_pose("robot1", 1.0, 3, np.zeros(3))
    log.close()
    assert FUSION_STATUS not in viewer_state(rrd, "sim_time", [NS])


def test_a_data_sets_true_landmark_ids_are_shown_clear_of_the_maps_landmarks(tmp_path):
    """A point's label box is drawn over the point, on top of everything: the true landmarks' ids hid the map's own
    landmarks beside them (MRCLAM: ~0.1 m off, a few pixels), the very comparison the data set view is for. Every
    label the 2-D map shows sits clear of the true landmarks; each id is still there, and still on its landmark for
    hovering."""
    rrd = tmp_path / "robot3.rrd"
    truth = np.array([[1.0, 2.0], [4.0, -1.0], [-2.0, 0.5]])
    ids = ["11", "12", "13"]
    log = MissionLog(open_recording(str(rrd)), ["robot3"], blueprint=False)
    log.log_true_landmarks("robot3", truth, labels=ids)
    estimate = landmark_map("robot3", 3, np.random.default_rng(4))
    estimate.positions = np.column_stack([truth + 0.08, np.zeros(3)])
    log.log_robot_landmarks("robot3", 10.0, None, estimate, confirm_count=1)
    log.close()

    shown = viewer_state(rrd, "sim_time", [10 * NS])
    anchors, texts = [], []
    for entity, at in shown.items():
        state = at[10 * NS]
        if entity.startswith("map/robot3") and state.get("Points2D:show_labels") == [True]:
            anchors += state["Points2D:positions"]
            texts += [str(label) for label in state["Points2D:labels"]]
    assert sorted(texts) == ids
    gaps = np.linalg.norm(np.array(anchors, float)[:, None] - truth[None], axis=2)
    assert gaps.min() >= 0.25, "a shown label sits on a true landmark: its box hides the estimate beside it"
    hover = shown["map/robot3/true_landmarks"][10 * NS]
    assert [str(label) for label in hover["Points2D:labels"]] == ids
    assert np.allclose(hover["Points2D:positions"], truth)
    assert len(shown["map/robot3/landmarks/confirmed"][10 * NS]["Points2D:positions"]) == 3


def _layout_views(rrd) -> set[tuple[str, str]]:
    """(class, origin) of every view of the layouts the recording carries (its blueprint stores)."""
    import rerun.chunk as rrchunk

    reader = rrchunk.RrdReader(rrd)
    views: set[tuple[str, str]] = set()
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            if "ViewBlueprint:class_identifier" in batch.schema.names:
                for kind, origin in zip(batch.column("ViewBlueprint:class_identifier").to_pylist(),
                                        batch.column("ViewBlueprint:space_origin").to_pylist(), strict=True):
                    if kind and origin:
                        views.add((str(kind[0]), str(origin[0]).strip("/")))
    return views


MISSION_SUMMARY = {
    "robots": {name: {"landmarks": 806 + k, "frames_processed": 540, "frames_dropped": 0,
                      "frames_without_odometry": 0, "final_position_error": 0.06, "odometry_position_error": 2.6,
                      "ms_per_frame": {"frontend": 8.4, "update": 25.5}} for k, name in enumerate(ROBOTS)},
    "duration": 143.8, "camera": "mock", "particles": 100, "seed": 0, "failures": [],
    "fusion": {"pairs": [{"reference": "robot1", "other": "robot2", "aligned": True, "tx": 4.992, "ty": 0.024,
                          "theta": 3.1382, "supports": 39, "required_supports": 33, "false_alarm_probability": 6.9e-11,
                          "common": 39, "start_sigma_xy": 0.457, "start_sigma_theta": 0.0632, "error_xy": 0.025,
                          "error_theta": 0.0034}],
               "merged_landmarks": 1718},
    "fusion_ms": 395.9, "fusions_during_mission": 7}


def test_the_missions_summary_is_shown_as_the_command_printed_it_in_a_tab_of_its_own(tmp_path):
    """mission/summary was logged (JSON in a code block) but no view of the layout showed it: a reviewer never saw
    the figures the demo prints (frames dropped, each robot's errors, the alignment table, the merged map)."""
    from runtime.report import format_summary
    from runtime.rerun_style import mission_blueprint

    rrd = tmp_path / "mission.rrd"
    log = MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS)), ROBOTS, blueprint=False)
    log.log_summary(MISSION_SUMMARY)
    log.close()
    text = str(viewer_state(rrd, "sim_time", [0])["mission/summary"][0]["TextDocument:text"][0])
    assert format_summary(MISSION_SUMMARY) in text
    assert "robot2 -> robot1" in text and "Merged map: 1718 landmarks" in text
    assert ("TextDocument", "mission/summary") in _layout_views(rrd)


def test_a_data_set_runs_figures_are_shown_too_as_a_table_of_readable_numbers(tmp_path):
    """A data set run's summary is its metrics, not a mission's: a table, one figure a row, 4 significant digits
    (the JSON block showed 0.08796996940001048), the review's JSON unchanged."""
    import json

    from runtime.rerun_read import read_recording
    from runtime.rerun_style import dataset_blueprint

    rrd = tmp_path / "robot3.rrd"
    figures = {"ate_m": 0.08796996940001048, "smoothed": True, "robot": "robot3", "frames": 5345,
               "warnings": ["only 60 % of the landmarks | within", "the frame rests on one sighting"]}
    log = MissionLog(open_recording(str(rrd), blueprint=dataset_blueprint("robot3")), ["robot3"], blueprint=False)
    log.log_summary(figures)
    log.close()
    text = str(viewer_state(rrd, "sim_time", [0])["mission/summary"][0]["TextDocument:text"][0])
    rows = text.splitlines()
    assert rows[:2] == ["| figure | value |", "|---|---|"]
    assert "| ate_m | 0.08797 |" in rows and "| smoothed | yes |" in rows and "| frames | 5345 |" in rows
    assert "| warnings | only 60 % of the landmarks \\| within; the frame rests on one sighting |" in rows
    assert ("TextDocument", "mission/summary") in _layout_views(rrd)
    assert read_recording(rrd).summary == json.loads(json.dumps(figures))


def test_the_landmark_count_plots_keep_their_legend_off_their_curves(tmp_path):
    """Counts that grow from 0 leave their plot's top left empty; the viewer's own corner (bottom left) put the four
    long legend lines of a robot's landmark counts over the curves' first minute (screenshots, session 49)."""
    import rerun.chunk as rrchunk

    from runtime.rerun_style import mission_blueprint

    rrd = tmp_path / "mission.rrd"
    MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS)), ROBOTS, blueprint=False).close()
    reader = rrchunk.RrdReader(rrd)
    names, corners = {}, {}
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            path = chunk.entity_path.strip("/")
            if "ViewBlueprint:display_name" in batch.schema.names:
                names[path] = str(batch.column("ViewBlueprint:display_name").to_pylist()[-1][0])
            if "PlotLegend:corner" in batch.schema.names:
                corners[path.rsplit("/", 1)[0]] = batch.column("PlotLegend:corner").to_pylist()[-1][0]
    counted = {view: name for view, name in names.items() if name.startswith("landmarks")}
    assert len(counted) == len(ROBOTS) + 1     # each robot's landmark counts, and the fusion's
    assert {corners.get(view) for view in counted} == {1}   # Rerun's Corner2D.LeftTop
