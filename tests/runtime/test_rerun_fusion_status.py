"""What a reviewer sees of the fusion in the viewer, read back from a saved recording with Rerun's own reader: each
pair's last fusion in words (aligned or why not, with its supports, P(chance), 1 σ and error) at the time shown,
the layout places it beside the fused map with the mission's events, the plots span the whole recording, and the 3-D
world says z is up (REP-103)."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.rerun_log import MissionLog
from runtime.rerun_sink import open_recording
from runtime.rerun_style import EVENTS, FUSION_STATUS, dataset_blueprint, mission_blueprint

from .rerun_helpers import ROBOTS, blueprint_views, entity_rows, landmark_map, viewer_state

NOT_ALIGNED = {"aligned": False, "tx": None, "ty": None, "theta": None, "supports": 9, "required_supports": 34,
               "false_alarm_probability": 1.0, "common": 0, "self_repeat_supports": 22, "second_best_supports": 7,
               "note": "ambiguous: one map repeats itself under a distinct transform with 22 supports",
               "error_xy": None, "error_theta": None}
ALIGNED = {"aligned": True, "tx": 12.5, "ty": -0.25, "theta": 3.1, "supports": 41, "required_supports": 13,
           "false_alarm_probability": 2.5e-9, "common": 37, "start_sigma_xy": 0.06, "start_sigma_theta": 0.004,
           "error_xy": 0.041, "error_theta": 0.0021}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rrd = tmp_path_factory.mktemp("status") / "m.rrd"
    log = MissionLog(open_recording(str(rrd)), ROBOTS, blueprint=False)
    log.log_alignment(20.0, "robot1", "robot2", NOT_ALIGNED)
    log.log_alignment(40.0, "robot1", "robot2", ALIGNED)
    log.close()
    return rrd


def test_the_fusion_status_says_why_a_pair_is_not_aligned_then_what_its_alignment_rests_on(recording):
    ns = 1_000_000_000
    shown = viewer_state(recording, "sim_time", [30 * ns, 50 * ns])[FUSION_STATUS]
    before, after = (str(shown[t]["TextDocument:text"][0]) for t in (30 * ns, 50 * ns))
    assert "robot2 → robot1" in before and "**not aligned**" in before
    assert "9 supports, 34 needed" in before and "repeats itself" in before
    assert "**aligned**" in after and "tx 12.500 m" in after and "41 supports (13 needed, P(chance) 2.5e-09)" in after
    assert "1σ 0.060 m / 0.0040 rad" in after and "error against the truth 0.041 m / 0.0021 rad" in after
    (media,) = {str(r["TextDocument:media_type"][0]) for r in entity_rows(recording, FUSION_STATUS)}
    assert media == "text/markdown"


def test_the_3d_world_says_z_is_up(recording):
    rows = [r for r in entity_rows(recording, "world") if r.get("ViewCoordinates:xyz") is not None]
    assert rows, "world carries no ViewCoordinates: the viewer guesses the up axis"
    # Rerun's ViewCoordinates: 1 Up, 2 Down, 3 Right, 4 Left, 5 Forward, 6 Back; RIGHT_HAND_Z_UP is (Right, Forward, Up)
    assert list(rows[-1]["ViewCoordinates:xyz"][0]) == [3, 5, 1]


def test_the_fused_map_has_the_fusion_status_beside_it_and_the_fusion_tab_the_events():
    tabs = mission_blueprint(ROBOTS).root_container
    by_name = {tab.name: list(blueprint_views(tab)) for tab in tabs.contents}
    for tab in ("overview", "fusion"):
        documents = [v for v in by_name[tab] if v.class_identifier == "TextDocument"]
        assert [str(v.origin).strip("/") for v in documents] == [FUSION_STATUS], tab
    logs = [v for v in by_name["fusion"] if v.class_identifier == "TextLog"]
    assert [str(v.origin).strip("/") for v in logs] == [EVENTS]


@pytest.mark.parametrize("blueprint", [mission_blueprint(ROBOTS), dataset_blueprint("robot2", smoothed=True)])
def test_every_plot_spans_the_whole_recording(blueprint):
    """The viewer's default time axis follows the cursor with a window of about a minute: a 30-minute data set's
    NEES would show a minute at a time."""
    plots = [v for v in blueprint_views(blueprint.root_container) if v.class_identifier == "TimeSeries"]
    assert plots
    for view in plots:
        axis = view.properties.get("TimeAxis")
        assert axis is not None, view.name
        (view_range,) = axis.view_range.as_arrow_array().to_pylist()
        assert view_range == {"start": None, "end": None}, (view.name, view_range)


def test_a_pair_found_once_and_not_confirmed_reads_as_not_yet_aligned(tmp_path):
    rrd = tmp_path / "c.rrd"
    log = MissionLog(open_recording(str(rrd)), ROBOTS, blueprint=False)
    note = ("candidate: 26 supports at (0.15 m, -0.01 m, -0.001 rad); no earlier fusion of these maps found it; "
            "the maps are still growing, so a fusion at least 20 s later must agree")
    log.log_alignment(20.0, "robot1", "robot2", {"aligned": False, "supports": 26, "note": note})
    log.close()
    # the logger of two robots also says "no fusion yet" at t = 0; the fusion of t = 20 s is the one read here
    (row,) = [r for r in entity_rows(rrd, FUSION_STATUS) if r["sim_time"].value == 20 * 10**9]
    text = str(row["TextDocument:text"][0])
    assert "**not yet aligned**: a candidate, not yet found (26 supports at (0.15 m" in text


def test_a_fusion_that_aligned_once_is_drawn_a_value_a_line_alone_would_not_draw(recording):
    """One aligned fusion (often the final one) is a single value of plots/fusion/error_xy: the series carries a
    marker style beside its line style; a dense series (ESS, every frame) keeps its line alone."""
    rows = entity_rows(recording, "plots/fusion/error_xy")
    assert [r["Scalars:scalars"] for r in rows if r.get("Scalars:scalars") is not None] == [[0.041]]
    assert any(r.get("SeriesPoints:names") == ["error xy (m)"] for r in rows)
    assert any(r.get("SeriesLines:names") == ["error xy (m)"] for r in rows)


def test_a_robot_on_its_own_gets_no_fused_map_and_no_fusion_tab_but_its_events():
    """``p3at run`` with one robot fuses nothing: an empty fused map and an empty status would only puzzle."""
    tabs = mission_blueprint(["robot1"]).root_container
    assert [t.name for t in tabs.contents] == ["overview", "robot1", "3-D", "summary"]
    views = list(blueprint_views(tabs))
    assert not [v for v in views if "fused" in str(v.origin) or str(v.origin).strip("/") == FUSION_STATUS]
    (overview,) = [t for t in tabs.contents if t.name == "overview"]
    assert [str(v.origin).strip("/") for v in blueprint_views(overview) if v.class_identifier == "TextLog"] == [EVENTS]


def _layout_names(rrd) -> set[str]:
    import rerun.chunk as rrchunk

    reader = rrchunk.RrdReader(rrd)
    names: set[str] = set()
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            if "ContainerBlueprint:display_name" in batch.schema.names:
                names |= {str(v[0]) for v in batch.column("ContainerBlueprint:display_name").to_pylist() if v}
    return names


def test_a_fusion_node_that_learns_its_robots_from_their_maps_sends_their_layout(tmp_path):
    """``p3at fuse --live --rerun file``: the node's logger starts with no robot (runtime/fleet/fusion_node.py) and
    learns them from the maps that come; its recording had no layout at all (the viewer's guess)."""
    rrd = tmp_path / "fusion.rrd"
    log = MissionLog(open_recording(str(rrd)), [])
    rng = np.random.default_rng(2)
    for robot in ROBOTS:
        log.log_map(robot, 1.0, landmark_map(robot, 6, rng))
    log.log_alignment(1.0, "robot1", "robot2", ALIGNED)
    log.close()
    assert {"overview", "robot1", "robot2", "fusion", "3-D"} <= _layout_names(rrd)
