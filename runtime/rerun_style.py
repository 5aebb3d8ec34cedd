"""How a recording looks in the viewer: each robot's colour and the other colours, each plotted series' legend name
and colour, the names of the text entities, and the layouts (blueprints) of a mission and of a data set's run.
Nothing is logged here: runtime/rerun_log.py's MissionLog logs with these and sends the mission's layout;
a caller may also hand a layout to runtime/rerun_sink.py's open_recording."""
from __future__ import annotations

import re
import zlib
from collections.abc import Iterable

from runtime.rerun_sdk import rrb

# -- colours and names: what a reader sees ------------------------------------------------------------------
ROBOT_COLOURS = [(230, 80, 60), (60, 130, 230), (70, 180, 90), (200, 160, 40), (160, 80, 200), (40, 180, 180)]


def robot_colour(robot: str) -> tuple[int, int, int]:
    """The robot's colour, the same in every process of a fleet: ``robotN`` gets the N-th colour of
    ROBOT_COLOURS, any other name one picked by a hash of the name."""
    digits = re.search(r"(\d+)$", robot)
    index = int(digits.group(1)) - 1 if digits else zlib.crc32(robot.encode())
    return ROBOT_COLOURS[index % len(ROBOT_COLOURS)]


def dimmed(colour: tuple[int, int, int], share: float = 0.45) -> tuple[int, int, int]:
    """``colour`` mixed with the dark background: provisional landmarks, odometry, particles."""
    return tuple(int(share * c + (1 - share) * 30) for c in colour)


SHARED_COLOUR = (255, 255, 255)     # fused landmarks seen by several robots
TRUE_COLOUR = (205, 205, 205)       # ground truth (mocks only)
WALL_COLOUR = (110, 110, 120)
MAP_BACKGROUND = (24, 24, 28)
FRAME_TIE_COLOUR = (255, 0, 200)    # the sighting a data set map's frame rests on, unchecked: no robot's colour

# plots/<robot>/<name> and plots/fusion/<name>: the legend name (with its unit) and colour of each series.
SERIES: dict[str, tuple[str, tuple[int, int, int]]] = {
    "ess": ("ESS (effective particles)", (230, 190, 60)),
    "landmarks/all": ("landmarks (all, best particle)", (150, 150, 150)),
    "landmarks/confirmed": ("landmarks (confirmed, best particle, unmerged)", (70, 180, 90)),
    "landmarks/provisional": ("landmarks (provisional, best particle)", (230, 140, 50)),
    # the exported map (FastSLAM.best_map: confirmed, coincident landmarks merged) at each snapshot: the count
    # the progress line and the summary give. Legends stay short: a long one covers the plot.
    "landmarks/map": ("landmarks (exported map, merged)", (90, 160, 230)),
    "observations": ("observations per frame", (90, 160, 230)),
    "dropped": ("frames dropped (total)", (230, 80, 60)),
    "time/frontend": ("time/frontend (ms)", (90, 160, 230)),
    "time/predict": ("time/predict (ms)", (230, 140, 50)),
    "time/update": ("time/update (ms)", (70, 180, 90)),
    "error_xy": ("error xy (m)", (230, 80, 60)),
    "error_theta": ("error θ (rad)", (160, 110, 230)),
    "common": ("common landmarks", (70, 180, 90)),
    "merged": ("merged landmarks", (240, 240, 240)),
    "self_check": ("self-check CUSUM (at the threshold: the map may have lost its place)", (200, 100, 160)),
    "self_check/threshold": ("self-check threshold", (150, 150, 150)),
    "pose_nees": ("pose NEES (χ²₃: 3 is consistent)", (230, 190, 60)),
}
_SPARE_COLOURS = [(40, 180, 180), (200, 100, 160), (180, 180, 80), (120, 200, 240)]
# series logged once per fusion or map snapshot (every 10-20 s), drawn with markers as well as lines: a fusion that
# aligned once (the final one) is a single value, which a line alone does not draw
SPARSE_SERIES = frozenset({"error_xy", "error_theta", "common", "merged", "landmarks/map", "self_check",
                           "self_check/threshold"})


def series_style(name: str) -> tuple[str, tuple[int, int, int]]:
    if name in SERIES:
        return SERIES[name]
    label = f"{name} (ms)" if name.startswith("time/") else name
    return label, _SPARE_COLOURS[zlib.crc32(name.encode()) % len(_SPARE_COLOURS)]


# -- the layout -------------------------------------------------------------------------------------------
FUSED_MAP_NAME = "fused map (aligned and merged, in the reference robot's start frame)"


def _map_view(key: str, name: str) -> rrb.Spatial2DView:
    """A top-down 2-D map of map/<key> (x right, y up: the flip logged at map/<key> sits below the origin)."""
    return rrb.Spatial2DView(origin="map", contents=[f"+ map/{key}/**"], name=name, background=MAP_BACKGROUND)


WHOLE_TIMELINE = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                       end=rrb.TimeRangeBoundary.infinite()))


def _plot(origin: str, name: str, contents: list[str] | None = None, legend=None) -> rrb.TimeSeriesView:
    """A plot whose time axis spans the whole recording (the viewer's default follows the time cursor with a window
    of about a minute: a 200 s mission's ESS, or a 30-minute data set's NEES, would show a minute at a time).
    ``legend``: the corner of its legend (None: the viewer's, bottom left)."""
    return rrb.TimeSeriesView(origin=origin, contents=contents or ["+ $origin/**"], name=name, axis_x=WHOLE_TIMELINE,
                              plot_legend=legend)


# counts that grow from 0 (landmarks): their plot's top left is empty, where the viewer's bottom-left legend (four
# long lines for a robot's landmarks) covered the curves' first minute
GROWING_LEGEND = rrb.PlotLegend(corner=rrb.Corner2D.LeftTop)


FUSION_STATUS = "fusion/status"
EVENTS = "mission/events"
SUMMARY = "mission/summary"


def _summary_tab(name: str = "the figures the command printed at its end") -> rrb.TextDocumentView:
    """The mission's summary (static: the same at every time), as the command printed it: the robots' landmarks,
    frames and errors, each alignment's figures, the merged map. Without a view it was logged and never shown."""
    return rrb.TextDocumentView(origin=SUMMARY, name=name)


def _fusion_status_view() -> rrb.TextDocumentView:
    """Each pair's last fusion in words (aligned or why not, supports, P(chance), 1 σ, error): a fused map that shows
    one robot's landmarks alone is then read as "not aligned (why)", not as a fusion that lost a map."""
    return rrb.TextDocumentView(origin=FUSION_STATUS, name="fusion status (the last fusion: aligned or why not)")


def _events_view(name: str = "mission events (warnings, fusion candidates, splits)") -> rrb.TextLogView:
    return rrb.TextLogView(origin=EVENTS, name=name)


def mission_blueprint(robots: Iterable[str]) -> rrb.Blueprint:
    """The layout, as tabs:

    - overview: each robot's top-down map in its own frame (the paper's Fig. 3), beside the fused map (Fig. 5) and
      the fusion's status in words;
    - one tab per robot: its map, its stereo pair with the matches, and its plots, each on its own axis;
    - fusion: the fused map; each pair's last fusion in words (aligned or why not, with what it rests on); the
      alignment's error (m, rad) and landmark counts, each on its own axis; the mission's events (warnings);
    - 3-D: the world with the robots, their cameras (pinholes, matched corners) and the landmarks; the covariance
      ellipsoids (1 σ) of each robot's map are hidden (tick them in the blueprint panel), the fused map's shown;
    - summary: the figures the command printed at its end (mission/summary).

    One robot (``p3at run`` on its own): nothing is fused, so no fused map and no fusion tab; the overview is its map
    above the mission's events.

    2-D entities sit only under 2-D views' origins or under a pinhole (the stereo images in the 3-D world).
    """
    robots = list(robots)
    maps = [_map_view(r, f"{r}: local map (own start frame)") for r in robots]
    robot_maps = rrb.Grid(*maps, grid_columns=1 if len(maps) <= 2 else 2) if maps else None
    fleet = len(robots) != 1
    # a view object is one place in the layout: each tab builds its own
    if fleet:
        fused_overview = rrb.Vertical(_map_view("fused", FUSED_MAP_NAME), _fusion_status_view(), row_shares=[5, 1])
        overview = rrb.Horizontal(*([robot_maps] if robot_maps else []), fused_overview,
                                  column_shares=[2, 3] if maps else None, name="overview")
    else:
        overview = rrb.Vertical(robot_maps, _events_view(), row_shares=[5, 1], name="overview")
    robot_tabs = []
    for r in robots:
        plots = rrb.Vertical(
            _plot(f"plots/{r}/ess", "ESS (effective particles)"),
            _plot(f"plots/{r}/landmarks", "landmarks: the best particle's and its exported map's (count)",
                  legend=GROWING_LEGEND),
            _plot(f"plots/{r}/observations", "observations per frame (count)"),
            _plot(f"plots/{r}/time", "time per stage (ms)"),
            _plot(f"plots/{r}/dropped", "frames dropped (total)"),
            _plot(f"plots/{r}/self_check", "self-check: old landmarks not re-detected (CUSUM)"),
            row_shares=[2, 3, 2, 2, 1, 2])  # the landmarks plot has four series, each legend line long
        robot_tabs.append(rrb.Horizontal(
            rrb.Vertical(_map_view(r, f"{r}: local map (own start frame)"),
                         rrb.Spatial2DView(origin=f"images/{r}/pair", name=f"{r}: stereo pair and matches"),
                         row_shares=[3, 2]),
            plots, column_shares=[3, 2], name=r))
    fusion = rrb.Horizontal(
        _map_view("fused", FUSED_MAP_NAME),
        rrb.Vertical(_fusion_status_view(),
                     _plot("plots/fusion/error_xy", "alignment error xy (m)"),
                     _plot("plots/fusion/error_theta", "alignment error θ (rad)"),
                     _plot("plots/fusion", "landmarks (count)", ["+ plots/fusion/merged", "+ plots/fusion/common"],
                           legend=GROWING_LEGEND),
                     _events_view(), row_shares=[2, 2, 2, 2, 2]),
        column_shares=[3, 2], name="fusion")
    hidden = {f"world/{r}/landmarks/covariance": rrb.EntityBehavior(visible=False) for r in robots}
    world = rrb.Horizontal(rrb.Spatial3DView(origin="world", name="3-D world", overrides=hidden), name="3-D")
    summary = rrb.Horizontal(_summary_tab(), name="summary")
    return rrb.Blueprint(rrb.Tabs(overview, *robot_tabs, *([fusion] if fleet else []), world, summary, active_tab=0),
                         collapse_panels=True)


def dataset_blueprint(robot: str, smoothed: bool = False, scored: bool = True,
                      truth_heading: str = "mocap", warned: bool = False) -> rrb.Blueprint:
    """The layout of one robot's run on a data set (runtime/dataset_recording.py): its 2-D map (estimated, dead
    reckoning and true paths, its landmarks over the true ones) beside the pose NEES over time; a 3-D tab with the
    landmarks' 1-σ ellipsoids shown (the point of a run with ground truth is to see whether they cover the truth).
    No fusion view: one robot, nothing fused. ``smoothed``: the map and path are the whole log's (``--smooth``), and
    the title says so (a path drawn as it grows is then hindsight, not what the robot knew at that time).
    ``scored`` False (a log without ground truth): no NEES plot, which would stay empty, and the map's title says the
    run is not scored instead of naming a grey true path that is not there. ``truth_heading`` "travel": the title
    says the true path's heading is turned onto the direction of travel (docs/fastslam.md, *The truth's heading*).
    ``warned``: the run's warnings (what ``p3at slam dataset`` prints) sit under the overview, where a reviewer of the
    recording reads them beside the map they are about."""
    estimate = "smoothed map and path (the whole log's)" if smoothed else "map and paths"
    truth = "grey: ground truth" if scored else "no ground truth: not scored"
    if scored and truth_heading == "travel":
        truth += ", its heading on the direction of travel"
    map_view = _map_view(robot, f"{robot}: {estimate} (own start frame; dimmed: dead reckoning; {truth})")
    if scored:
        nees = _plot(f"plots/{robot}/pose_nees", "pose NEES against the ground truth (χ²₃: 3 is consistent)")
        overview = rrb.Horizontal(map_view, nees, column_shares=[3, 2], name="overview")
    else:
        overview = rrb.Horizontal(map_view, name="overview")
    if warned:
        overview = rrb.Vertical(overview, _events_view("warnings about this map (as `p3at slam dataset` prints them)"),
                                row_shares=[5, 1], name="overview")
    world = rrb.Horizontal(rrb.Spatial3DView(origin="world", name="3-D world (landmarks with 1-σ ellipsoids)"),
                           name="3-D")
    summary = rrb.Horizontal(_summary_tab("the run's figures (the keys of `p3at slam dataset --json`)"), name="summary")
    return rrb.Blueprint(rrb.Tabs(overview, world, summary, active_tab=0), collapse_panels=True)


__all__ = ["EVENTS", "FRAME_TIE_COLOUR", "FUSED_MAP_NAME", "FUSION_STATUS", "MAP_BACKGROUND", "ROBOT_COLOURS", "SERIES",
           "SHARED_COLOUR", "SPARSE_SERIES", "SUMMARY", "TRUE_COLOUR", "WALL_COLOUR", "WHOLE_TIMELINE",
           "dataset_blueprint", "dimmed", "mission_blueprint", "robot_colour", "series_style"]
