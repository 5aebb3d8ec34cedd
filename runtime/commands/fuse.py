"""``p3at fuse``: align landmark maps of several robots (RANSAC) and merge them into one (Kalman).

Exit status: 0 fused; 1 the maps (or some of them) do not overlap, or (``--live``) no two robots' maps came, so
nothing was fused; 2 bad arguments, an unreadable map file, or two maps holding the same estimates (a map twice, a
copy of it, or a fused map beside a map it holds).
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from estimation.errors import EstimationError
from estimation.landmark_map import LandmarkMap
from runtime.commands.options import (
    RERUN_KEYWORDS,
    OutputPathError,
    check_output_apart,
    check_output_file,
    non_negative_int,
    recording_id,
    rerun_sink_problem,
    same_file,
    start_sigmas,
)
from runtime.fusion_report import LOW_CONFIDENCE_PROBABILITY, confidence_text, sigmas
from runtime.json_output import json_text
from runtime.report import rests_on_prior_text

EXIT_NO_OVERLAP = 1
EXIT_BAD_INPUT = 2
# gate inflation (covariance scale) above which the maps' covariances are reported as too small: σ off by 2×
OVERCONFIDENT_MAPS = 4.0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "fuse", help="align and merge landmark maps of several robots",
        description="Align landmark maps pairwise by RANSAC on their descriptors and positions, pick the "
                    "strongest alignments (maximum spanning tree over support counts) and merge every map "
                    "into the first map's frame by a Kalman update of the common landmarks. Prints each "
                    "alignment (tx, ty, θ of the other map's frame in the first's), its supports and the "
                    "landmark counts; where maps carry metadata.true_start_pose (simulated maps) also the "
                    "alignment error against the truth; where they carry metadata.slam_frames (maps the "
                    "runtime saved) the camera frames each robot received, mapped, dropped, with a warning "
                    "for a starved run; where they carry metadata.vote (maps voted from several runs) a "
                    "warning naming the landmarks the runs disagree on. Exit status 1 when maps do not overlap "
                    "(--live: when no two robots' maps came).")
    parser.add_argument("maps", nargs="*", metavar="MAP", help="landmark-map files (.npz), at least two")
    parser.add_argument("--out", default=None, metavar="MERGED",
                        help="merged map file to write (.npz); required unless --live")
    parser.add_argument("--preset", choices=("paper", "robust"), default="robust",
                        help="alignment preset: the paper's published RANSAC or the robust one (default)")
    parser.add_argument("--method", type=int, choices=(1, 2), default=1,
                        help="common landmarks: 1 = RANSAC supports (default), 2 = nearest in position")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="random seed of RANSAC, >= 0 (default 0)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    parser.add_argument("--start-pose", action="append", default=[], metavar="MAP=X,Y,YAW[,SIGMA_XY,SIGMA_YAW]",
                        help="a rough start pose of one map's robot in a frame common to all (the lab's; metres, "
                             "radians, REP-103), MAP its index (0, 1, ...) or robot name (with --live: its robot "
                             "name); repeat per map. Every pair of maps with a start gets a prior on its relative "
                             "start: a best alignment outside it (χ²₃ 99.9 %%) is reported not found, never the best "
                             "one inside (default: none)")
    parser.add_argument("--start-sigma", type=start_sigmas, default=None, metavar="SIGMA_XY,SIGMA_YAW",
                        help="standard deviations of each --start-pose given without its own (m, rad; e.g. 1,0.3)")
    parser.add_argument("--start-poses", default=None, metavar="FILE.json",
                        help='start poses from a file: {"sigma_xy": 1, "sigma_yaw": 0.3, "starts": {"robot1": '
                             '[x, y, yaw], "robot2": [x, y, yaw, sigma_xy, sigma_yaw]}} (keys: names or indices)')
    # the live fusion node of a fleet (runtime/fleet, docs/fleet.md)
    from runtime.fleet.options import add_exchange_arguments, add_live_arguments

    parser.add_argument("--live", action="store_true",
                        help="run the fleet's fusion node: subscribe to the robots' maps over --exchange (default "
                             "zenoh), fuse on new data and at --interval, publish p3at/FLEET/fused/map")
    add_exchange_arguments(parser, default="zenoh")
    add_live_arguments(parser)
    # as `p3at run --recording-id` (runtime/mission_cli.py): the node's recording and the robots' then read as one
    parser.add_argument("--recording-id", type=recording_id, default=None, metavar="ID",
                        help="--live: Rerun recording id shared with the robots' `p3at run --recording-id ID`, so "
                             "that the node's recording and theirs open (and p3at review reads them) as one "
                             "(default: a new id)")
    parser.set_defaults(handler=_fuse)


class _Refused(Exception):
    """Why nothing is fused, in one line: said as 'p3at fuse: ...', exit EXIT_BAD_INPUT."""


def _refuse(why: Exception | str) -> int:
    print(f"p3at fuse: {why}", file=sys.stderr)
    return EXIT_BAD_INPUT


def _fuse(args: argparse.Namespace) -> int:
    from fusion import FusionError

    if args.live:
        return _fuse_live(args)
    try:
        maps = _read_maps(args)
    except _Refused as e:
        return _refuse(e)
    names = [m.robot for m in maps]
    if len(set(names)) < len(names):
        print("p3at fuse: note: several maps name the same robot; seen_by cannot tell them apart", file=sys.stderr)
    _warn_mixed_truth_headings(maps)
    try:
        priors = _priors(args, maps)
        alignments, checked = _align_and_merge(args, maps, priors)
    except FusionError as e:
        return _refuse(e)
    report = _report(args, maps, alignments, checked)
    if checked.fusion is None:
        report["overlap"] = False
        report["message"] = checked.message
        _print(report, args.json)
        _warn(report)
        print(f"p3at fuse: {checked.message}", file=sys.stderr)
        return EXIT_NO_OVERLAP
    _place_maps(report, maps, checked)
    _add_merge_figures(report, args.maps, checked)
    try:
        checked.fusion.map.save(args.out)
    except OSError as e:
        return _refuse(f"cannot write {args.out}: {e}")
    report["out"] = args.out
    _print(report, args.json)
    _warn(report)
    if report["unconnected"]:
        print("p3at fuse: these maps overlap no other map and were left out: "
              + ", ".join(report["unconnected"]), file=sys.stderr)
        return EXIT_NO_OVERLAP
    return 0


def _fuse_live(args: argparse.Namespace) -> int:
    """``--live``: the fleet's fusion node (runtime/fleet/fusion_node.py), after the checks of its arguments."""
    from fusion import FusionError
    from runtime.commands.file_kinds import out_problem
    from runtime.fleet.fusion_node import run_live

    try:
        if args.maps:   # the node fuses what the robots send: map files given were ignored without a word
            raise OutputPathError(f"map files ({args.maps[0]}{', ...' if len(args.maps) > 1 else ''}) do not "
                                  "apply to --live: the node fuses the maps the robots send; fuse files "
                                  "without --live")
        check_output_file(args.out)
        check_output_apart(args.out, files={"--start-poses": args.start_poses})
        if args.out is not None and (problem := out_problem(args.out, "map")) is not None:
            raise OutputPathError(problem)
        if (problem := rerun_sink_problem(args.rerun, RERUN_KEYWORDS)) is not None:
            raise OutputPathError(problem)
        starts = _live_starts(args)
    except (FusionError, OutputPathError) as e:
        return _refuse(e)
    return run_live(args, starts)


def _read_maps(args: argparse.Namespace) -> list[LandmarkMap]:
    """The map files, read once the arguments and --out are checked, and refused if they are not independent
    evidence (:func:`_not_independent`). Raises _Refused, or OutputPathError for --out (runtime/cli.py says it in
    one line, exit 2), before any map is read."""
    from runtime.commands.file_kinds import out_problem, wrong_kind

    if args.out is None:
        raise _Refused("give the merged map file to write with --out MERGED")
    if len(args.maps) < 2:
        raise _Refused("give at least two map files")
    check_output_file(args.out)
    check_output_apart(args.out, files={"--start-poses": args.start_poses})
    if (problem := out_problem(args.out, "map")) is not None:   # a noise model, a recording, a sensor log
        raise OutputPathError(problem)
    twice = next(((a, b) for i, a in enumerate(args.maps) for b in args.maps[i + 1:] if same_file(a, b)), None)
    if twice is not None:
        raise _Refused(f"{twice[0]} is given twice{'' if twice[0] == twice[1] else f' (as {twice[1]})'}: a map "
                       "fused with itself would count every landmark twice and halve its covariance")
    if any(same_file(args.out, path) for path in args.maps):
        raise _Refused(f"--out {args.out} is one of the input maps: the merged map would replace it; give "
                       "another file")
    problem = next((p for p in (wrong_kind(path, "map") for path in args.maps) if p is not None), None)
    if problem is not None:   # a recording or a sensor log: said so, with the command that reads it
        raise _Refused(problem)
    try:
        maps = [LandmarkMap.load(path) for path in args.maps]
    except EstimationError as e:
        raise _Refused(str(e)) from None
    if (problem := _not_independent(args.maps, maps)) is not None:
        raise _Refused(problem)
    return maps


def _not_independent(paths: list[str], maps: list[LandmarkMap]) -> str | None:
    """Why two of the maps are not independent evidence, so that a merge would count the same evidence twice and
    halve its covariance (None: they are): the same estimates, maps of one log, or a fused map that holds another."""
    shared = _shared_estimates(maps)
    if shared is not None:   # no independent evidence: a merge would be confidently wrong, so none is made
        (i, j), count = shared
        return (f"{paths[i]} and {paths[j]} hold the same estimates ({count} of "
                f"{min(len(maps[i]), len(maps[j]))} landmark positions equal bit for bit: a copy, or a fused map that "
                "already holds the other): fusing them would count those landmarks twice and halve their covariance; "
                "give only one of them")
    same_log = _same_log(maps)
    if same_log is not None:   # their errors are the same sightings' and odometry's: not independent evidence
        (i, j), log = same_log
        return (f"{paths[i]} and {paths[j]} are maps of the same log ({log}) over overlapping "
                "times: their errors are shared, so fusing them would halve the covariances on no new evidence; give "
                "one of them")
    return _held_maps(paths, maps)


def _align_and_merge(args: argparse.Namespace, maps: list[LandmarkMap], priors: dict):
    """(every pair's alignment, fusion.split's CheckedFusion): the maps aligned pairwise (RANSAC, seeded by --seed)
    and merged; a map that flagged itself is split at its alarm and each part aligned (fusion/split.py). Raises
    FusionError."""
    from fusion.multi import pairwise_alignments
    from fusion.split import fuse_checked

    rng = np.random.default_rng(args.seed)
    alignments = pairwise_alignments(maps, args.preset, rng, priors=priors)
    checked = fuse_checked(maps, preset=args.preset, method=args.method, alignments=alignments, priors=priors)
    return alignments, checked


def _report(args: argparse.Namespace, maps: list[LandmarkMap], alignments: dict, checked) -> dict:
    """The report of the maps and of every pair's alignment (``--json`` prints it whole), before the merge's own
    figures (:func:`_place_maps`, :func:`_add_merge_figures`)."""
    report = {"preset": args.preset, "method": args.method, "maps": [], "alignments": [], "out": None}
    splits = {c.index: c.to_dict() for c in checked.checks}
    by_index = {c.index: c for c in checked.checks if c.decision != "whole"}   # maps split at their alarm
    for k, (path, m) in enumerate(zip(args.maps, maps, strict=True)):
        report["maps"].append({"file": path, "robot": m.robot, "landmarks": len(m), **_frame_figures(path, m),
                               **_self_check_figures(path, m), **_vote_figures(path, m), "split": splits.get(k)})
    tree = _whole_tree(checked)
    for (i, j), a in sorted(alignments.items()):
        split = [(k, c) for k, c in ((0, by_index.get(i)), (1, by_index.get(j))) if c is not None]
        report["alignments"].append(_alignment_entry(i, j, a, (i, j) in tree, split, maps))
    return report


def _whole_tree(checked) -> set[tuple[int, int]]:
    """The merge's tree edges between maps merged whole, both ways round (a split map's parts were placed by their
    own alignments)."""
    src, result = checked.sources, checked.fusion
    tree = set() if result is None else {(src[p][0], src[c][0]) for p, c in result.tree
                                         if src[p][1] is None and src[c][1] is None}
    return tree | {(c, p) for p, c in tree}


def _alignment_entry(i: int, j: int, a, used: bool, split: list, maps: list[LandmarkMap]) -> dict:
    """One pair's alignment as the report gives it, with its error against the true start poses where the maps
    carry them; ``split``: (column of the supports, SplitCheck) of the pair's maps split at their alarm."""
    from fusion import alignment_error, true_relative_pose
    from fusion.alignment import alignment_error_xy_theta

    entry = {"map1": i, "map2": j, "used": used, **a.to_dict()}
    entry["supports_count"] = len(a.supports)
    entry["prior_text"] = None if a.prior is None else a.prior.text()
    p = a.statistics.false_alarm_probability
    entry["false_alarm_probability"] = float(p) if np.isfinite(p) else None
    entry["low_confidence"] = bool(a.found and not (p <= LOW_CONFIDENCE_PROBABILITY))
    apart = _apart_from_start(a, split, maps) if a.found else ""
    if apart:   # its start-frame 1σ claims a start the gap broke: only its own precision (covariance) holds
        entry["start_covariance"] = None
        entry["start_covariance_not_comparable"] = apart
    truth = true_relative_pose(maps[i], maps[j])
    if truth is not None:
        entry["true_pose"] = [float(v) for v in truth]
        scored = a.found and not apart
        entry["error"] = None if not scored else [float(v) for v in alignment_error(a.pose, truth)]
        entry["error_xy"], entry["error_theta"] = alignment_error_xy_theta(a.pose, truth) if scored else (None, None)
        if a.found and apart:
            entry["error_not_comparable"] = apart
    return entry


def _place_maps(report: dict, maps: list[LandmarkMap], checked) -> None:
    """Each map's (or split map's part's) pose in the merged frame, into the report; with its error against the true
    start poses where the maps carry them, and the merge weights where the merge took them from the residuals."""
    from fusion import alignment_error, true_relative_pose
    from fusion.alignment import alignment_error_xy_theta
    from fusion.multi import claimed_variance
    from fusion.split import PARTS, holds_start

    result = checked.fusion
    by_index = {c.index: c for c in checked.checks if c.decision != "whole"}   # maps split at their alarm
    root, root_part = checked.sources[result.reference]
    framed = holds_start(root_part)   # else the fused frame is the reference's part after its gap
    for i, pose in enumerate(result.poses):
        k, part = checked.sources[i]
        if part is not None:      # a part of a split map: its own placement
            report["maps"][k]["split"]["parts"][PARTS.index(part)]["pose_in_reference"] = (
                None if pose is None else [float(v) for v in pose])
            continue
        report["maps"][k]["pose_in_reference"] = None if pose is None else [float(v) for v in pose]
        truth = true_relative_pose(checked.inputs[result.reference], maps[k])
        if pose is not None and truth is not None and i != result.reference:
            if framed:
                report["maps"][k]["pose_error"] = [float(v) for v in alignment_error(pose, truth)]
                report["maps"][k]["error_xy"], report["maps"][k]["error_theta"] = alignment_error_xy_theta(pose,
                                                                                                         truth)
            else:
                report["maps"][k]["error_not_comparable"] = by_index[root].apart_from_start()
        if result.covariance_scales is not None:      # merge weights from the pairwise residuals (fusion.multi)
            claimed = float(np.sqrt(claimed_variance(maps[k])))
            report["maps"][k]["covariance_scale"] = result.covariance_scales[i]
            report["maps"][k]["merge_sigma"] = claimed * float(np.sqrt(result.covariance_scales[i]))
            report["maps"][k]["claimed_sigma"] = claimed


def _add_merge_figures(report: dict, paths: list[str], checked) -> None:
    """The merged map's counts into the report: its landmarks, those common to several maps, the maps it left out,
    and the identities two maps placed beyond their covariances apart."""
    result = checked.fusion
    report["merged_landmarks"] = len(result.map)
    report["common_landmarks"] = int(sum(len(m) for i, m in enumerate(checked.inputs) if result.rows[i] is not None)
                                     - len(result.map))
    merged = {checked.sources[i][0] for i, rows in enumerate(result.rows) if rows is not None}
    report["unconnected"] = [path for k, path in enumerate(paths) if k not in merged]   # or left out by a split
    report["overlap"] = not report["unconnected"]
    # known-ID maps placing one identity beyond their covariances apart: the merged map holds it once (fusion.merging)
    report["identity_conflicts"] = list(result.map.metadata.get("identity_conflicts", []))


def _apart_from_start(alignment, split: list, maps: list[LandmarkMap]) -> str:
    """Why a whole-map alignment's error against the true start poses is not its error, or "": some of its supports
    lie in the part of a split map (``split``: (column of the supports, fusion.split.SplitCheck)) made after its gap,
    which does not share that map's start (fusion/split.py); the alignment then places that part's frame."""
    why = []
    for column, check in split:
        ids = maps[check.index].ids[np.asarray(alignment.supports, np.int64).reshape(-1, 2)[:, column]]
        after = int(np.count_nonzero(ids >= check.first_id))
        if after:
            why.append(f"{after} of its {len(ids)} supports in {check.robot}'s map lie in "
                       + check.apart_from_start().replace(" does not", ", which does not", 1))
    return "; ".join(why)


def _shared_estimates(maps: list[LandmarkMap]) -> tuple[tuple[int, int], int] | None:
    """The first pair of maps of which more than half the smaller's landmark positions also stand, bit for bit, in
    the other, with how many: the same estimates twice (two runs never give equal float64 positions), so no
    independent evidence to merge. None when no pair does."""
    rows = [{row.tobytes() for row in np.ascontiguousarray(m.positions)} for m in maps]
    for i in range(len(maps)):
        for j in range(i + 1, len(maps)):
            count = len(rows[i] & rows[j])
            if count and 2 * count > min(len(rows[i]), len(rows[j])):
                return (i, j), count
    return None


def _same_log(maps: list[LandmarkMap]) -> tuple[tuple[int, int], str] | None:
    """The first pair of maps made from one data set's log (the same ``metadata["dataset"]``, e.g. two seeds of
    ``p3at slam dataset``) whose trajectories' times overlap (or either has none), with the log's name: the Kalman
    merge takes maps as independent, and these share their readings. None when no pair does: two missions of one
    robot are new evidence."""
    def span(m: LandmarkMap) -> tuple[float, float] | None:
        times = m.trajectory[:, 0] if len(m.trajectory) else None
        return None if times is None else (float(times.min()), float(times.max()))

    for i in range(len(maps)):
        for j in range(i + 1, len(maps)):
            log = maps[i].metadata.get("dataset")
            if not log or log != maps[j].metadata.get("dataset"):
                continue
            a, b = span(maps[i]), span(maps[j])
            if a is None or b is None or (a[0] <= b[1] and b[0] <= a[1]):
                return (i, j), str(log)
    return None


def _held_maps(paths: list[str], maps: list[LandmarkMap]) -> str | None:
    """Why the maps cannot be fused when a fused map among them already holds another of them (the other's content
    fingerprint is among those it records: its landmarks would count twice), else None. A fused map beside another
    map of a robot it holds gets a note on stderr: certainly a different map where the fused map records
    fingerprints (another run of that robot: new evidence), possibly the same map where it does not (older files).
    """
    from fusion.provenance import content_fingerprint, held_fingerprints

    prints = [content_fingerprint(m) for m in maps]
    fused = [(k, m.metadata["fusion"], held_fingerprints(m)) for k, m in enumerate(maps)
             if isinstance(m.metadata.get("fusion"), dict)]
    pairs = [(k, j, fusion, holds) for k, fusion, holds in fused for j in range(len(maps)) if j != k]
    for k, j, _, holds in pairs:
        if holds is not None and prints[j] in holds:
            return (f"{paths[k]} is a fused map that already holds {paths[j]} (its map of {maps[j].robot}, fingerprint "
                    f"{prints[j]}): fusing them would count its landmarks twice and halve their covariance; leave "
                    f"{paths[j]} out (its landmarks are in {paths[k]} already)")
    for k, j, fusion, holds in pairs:
        robots = fusion.get("maps")
        if isinstance(robots, list) and maps[j].robot in robots:
            print(f"p3at fuse: note: {paths[k]} is a fused map that already holds a map of {maps[j].robot}; "
                  + (f"{paths[j]} is another one (its fingerprint {prints[j]} is not among those {paths[k]} "
                     "records), fused as new evidence" if holds is not None else
                     f"if {paths[j]} is that map, its landmarks count twice (the fused map was written before maps "
                     "recorded their sources' fingerprints, so it cannot tell)"), file=sys.stderr)
    return None


def _priors(args: argparse.Namespace, maps: list[LandmarkMap]) -> dict:
    """{(i, j): StartPrior} from --start-pose / --start-poses (fusion.prior.pair_priors); raises FusionError, also for
    a start given for one map only (it makes no prior); warns on stderr which maps have none when others do."""
    from fusion.errors import IncompatibleMapsError
    from fusion.prior import pair_priors

    names = [m.robot for m in maps]
    starts = {}
    for key, start in _given_starts(args).items():
        index = int(key) if key.isdigit() else (names.index(key) if key in names else None)
        if index is None or index >= len(maps):   # an index past the last map ended in IndexError (exit 70)
            raise IncompatibleMapsError(f"a start names map {key!r}, which is neither an index (0 to "
                                        f"{len(maps) - 1}) nor a robot of the maps ({', '.join(names)})")
        starts[index] = start
    if len(starts) == 1:
        (only,) = starts
        raise IncompatibleMapsError(f"a start pose for map {only} ({names[only]}) alone gives no prior: " + _ONE_START)
    missing = [f"{k} ({names[k]})" for k in range(len(maps)) if starts and k not in starts]
    if missing:
        print(f"p3at fuse: warning: no start pose for map{'s' if len(missing) > 1 else ''} {', '.join(missing)}: "
              f"{'their' if len(missing) > 1 else 'its'} pairs are aligned without a prior", file=sys.stderr)
    return pair_priors(starts, len(maps), source="given start poses") if starts else {}


# a prior is on two robots' relative start: one start alone constrains nothing
_ONE_START = "a prior is on the relative start of two maps, so give the start of another map too"


def _given_starts(args: argparse.Namespace) -> dict[str, tuple]:
    """{key: (pose, (σ xy, σ yaw))} from --start-poses FILE and --start-pose KEY=... (which wins), each start's σ
    its own or --start-sigma; raises FusionError (IncompatibleMapsError) with a one-line reason."""
    from fusion.errors import IncompatibleMapsError
    from fusion.prior import load_starts, parse_start

    given: dict[str, tuple] = {}
    if args.start_poses is not None:
        given.update(load_starts(args.start_poses))
    for item in args.start_pose:
        key, sep, value = item.partition("=")
        if not sep:
            raise IncompatibleMapsError(f"--start-pose is MAP=X,Y,YAW[,SIGMA_XY,SIGMA_YAW]; got {item!r}")
        given[key.strip()] = parse_start(value)
    starts = {}
    for key, (pose, sig) in given.items():
        sig = sig if sig is not None else args.start_sigma
        if sig is None or not all(np.isfinite(sig)):
            raise IncompatibleMapsError(f"the start of map {key!r} has no standard deviations: give them in it or "
                                        "with --start-sigma SIGMA_XY,SIGMA_YAW")
        starts[key] = (pose, tuple(sig))
    return starts


def _live_starts(args: argparse.Namespace) -> dict[str, tuple]:
    """The live node's starts, by robot name: its maps arrive by robot, so a map index means nothing there."""
    from fusion.errors import IncompatibleMapsError

    starts = _given_starts(args)
    numbered = sorted(k for k in starts if k.isdigit())
    if numbered:
        raise IncompatibleMapsError(f"the live fusion node knows maps by robot name, not by index: give "
                                    f"--start-pose ROBOT=X,Y,YAW (got {', '.join(numbered)})")
    if len(starts) == 1:
        (only,) = starts
        raise IncompatibleMapsError(f"a start pose for {only} alone gives no prior: " + _ONE_START)
    return starts


def _print(report: dict, as_json: bool) -> None:
    if as_json:
        print(json_text(report))
        return
    for k, m in enumerate(report["maps"]):
        frames = m["slam_frames"]
        print(f"map {k}: {m['file']} ({m['robot']}, {m['landmarks']} landmarks"
              + ("" if frames is None else f"; frames: {frames['received']} received, {frames['processed']} "
                 f"mapped, {frames['dropped']} dropped, {frames['without_odometry']} without odometry") + ")")
    for a in report["alignments"]:
        head = f"align map {a['map2']} -> map {a['map1']} [{a['preset']}]"
        st = a["statistics"]
        if not a["found"]:
            print(f"{head}: no overlap ({a['reason']})")
            continue
        if a.get("prior") is not None:
            print(f"    {a['prior_text']}; this alignment χ² {st['prior_chi2']:.1f}, "
                  f"{st['outside_prior_supports']} supports at best outside it")
        tx, ty, th = a["pose"]
        rms = st["residual_rms"]
        print(f"{head}: tx={tx:+.3f} m ty={ty:+.3f} m θ={th:+.4f} rad; supports {a['supports_count']} of "
              f"{st['correspondences']} correspondences ({st['required_supports']} needed on these maps, best "
              f"distinct hypothesis {st['second_best_supports']}), {st['iterations']} iterations, residual rms "
              f"{rms:.3f} m; {confidence_text(a['false_alarm_probability'])}" + ("" if a["used"] else " (not used)"))
        if a["covariance"] is not None:
            sigma_xy, sigma_theta = sigmas(a["covariance"])
            print(f"    precision (1σ): {sigma_xy:.3f} m, {sigma_theta:.4f} rad")
        if a.get("start_covariance") is not None:
            sigma_xy, sigma_theta = sigmas(a["start_covariance"])
            print(f"    against the true start frames (1σ, each map's error at the overlap as a whole): "
                  f"{sigma_xy:.3f} m, {sigma_theta:.4f} rad")
        elif a.get("start_covariance_not_comparable"):
            print(f"    against the true start frames: no 1σ (the precision above is of the part's own alignment): "
                  f"{a['start_covariance_not_comparable']}")
        if st.get("gate_inflation", 1.0) > OVERCONFIDENT_MAPS:
            print(f"    note: the supports' residuals are {np.sqrt(st['gate_inflation']):.1f}× the maps' claimed "
                  "standard deviations (their covariances are too small; gate and precision were scaled to match)")
        if a["low_confidence"]:
            print("    warning: low confidence - maps that do not overlap could give this much support")
        if a.get("rests_on_prior"):      # the maps alone would not find it (fusion.Alignment.prior_backing)
            print(f"    {a['rests_on_prior']}")
        if a.get("error_xy") is not None:
            print(f"    error vs true start poses: error xy {a['error_xy']:.3f} m, error θ {a['error_theta']:.4f} rad")
        elif a.get("error_not_comparable"):
            print(f"    error vs true start poses: not comparable: {a['error_not_comparable']}")
    if len(report["maps"]) > 2:
        for k, m in enumerate(report["maps"]):
            if m.get("pose_in_reference") is not None and k:
                tx, ty, th = m["pose_in_reference"]
                line = f"map {k} in map 0's frame: tx={tx:+.3f} m ty={ty:+.3f} m θ={th:+.4f} rad"
                if m.get("error_xy") is not None:
                    line += f" (error xy {m['error_xy']:.3f} m, error θ {m['error_theta']:.4f} rad vs truth)"
                elif m.get("error_not_comparable"):
                    line += f" (error vs truth not comparable: {m['error_not_comparable']})"
                print(line)
    if any("merge_sigma" in m for m in report["maps"]):
        print("merge weights (σ about a rigid placement from the pairwise residuals, plus one standard error; "
              "σ the map claims): " + ", ".join(
            f"{m['robot']} {m['merge_sigma']:.3f} m ({m['claimed_sigma']:.3f} m)" for m in report["maps"]
            if "merge_sigma" in m))
    for k, m in enumerate(report["maps"]):
        if m.get("split") is not None:
            print(f"map {k} ({m['robot']}) {m['split']['text']}")
    if report.get("out"):
        print(f"merged map: {report['merged_landmarks']} landmarks ({report['common_landmarks']} common) "
              f"-> {report['out']}")


def _warn(report: dict) -> None:
    """The report's warnings on stderr, after its lines (a report with no merge has no identity conflicts)."""
    _warn_low_confidence(report)
    _warn_prior_backed(report)
    _warn_starved(report)
    _warn_lost(report)
    _warn_contested(report)
    _warn_identity_conflicts(report)


def _own_metadata(path: str, landmark_map: LandmarkMap, read, what: str):
    """What ``read(metadata)`` finds in a one-robot map's metadata; None for merged maps, which keep their
    reference map's metadata. A malformed entry is a one-line note naming ``what`` is not shown: the map itself is
    usable and is fused."""
    if len(landmark_map.robots) > 1:
        return None
    try:
        return read(landmark_map.metadata)
    except ValueError as e:
        print(f"p3at fuse: note: {path}: {e}; {what} not shown", file=sys.stderr)
        return None


def _frame_figures(path: str, landmark_map: LandmarkMap) -> dict:
    """A map's camera-frame counts and, for a starved run, why (runtime/slam_frames.py); None for maps that carry
    none (older maps, data sets' maps) and for merged maps."""
    from runtime.slam_frames import read_frame_counts, starved

    counts = _own_metadata(path, landmark_map, read_frame_counts, "its frame counts are")
    return {"slam_frames": counts, "starved": None if counts is None else starved(counts)}


def _warn_mixed_truth_headings(maps: list[LandmarkMap]) -> None:
    """Maps whose true starts hold headings from different truths are not scored against each other (their headings
    differ by the truth's own offset, up to 0.017 rad on MRCLAM): say so once."""
    from fusion import truth_heading

    headings = {}
    for k, m in enumerate(maps):
        if "true_start_pose" in m.metadata:
            headings.setdefault(truth_heading(m), []).append(str(k))
    if len(headings) > 1:
        kinds = "; ".join(f"{kind}: map{'s' if len(ks) > 1 else ''} {', '.join(ks)}" for kind, ks in headings.items())
        print(f"p3at fuse: warning: the maps' true starts hold headings from different truths ({kinds}; `p3at slam "
              "dataset --truth-heading`): alignments between them are not scored", file=sys.stderr)


def _warn_starved(report: dict) -> None:
    for k, m in enumerate(report["maps"]):
        if m["starved"] is not None:
            print(f"p3at fuse: warning: map {k} ({m['robot']}) comes from a starved run: {m['starved']}; it covers "
                  "less of its route than the robot drove", file=sys.stderr)


def _self_check_figures(path: str, landmark_map: LandmarkMap) -> dict:
    """A map's self-check verdict (runtime/map_self_check.py) and, if it flagged itself, why; None for maps that
    carry none (older maps) and for merged maps."""
    from runtime.map_self_check import lost_text, read_self_check

    verdict = _own_metadata(path, landmark_map, read_self_check, "its self-check is")
    return {"self_check": verdict, "lost": None if verdict is None else lost_text(verdict)}


def _warn_lost(report: dict) -> None:
    for k, m in enumerate(report["maps"]):
        if m["lost"] is not None:
            print(f"p3at fuse: warning: map {k} ({m['robot']}) {m['lost']}; if so, the map after that is not "
                  "tied to the map before it, so the map was split there and each part aligned (the line 'map "
                  f"{k} ({m['robot']}) flagged itself' says what was decided; the check also flags some healthy maps: "
                  "docs/fastslam-history.md, Session 7: self-check)", file=sys.stderr)


def _vote_figures(path: str, landmark_map: LandmarkMap) -> dict:
    """A voted map's record of its vote (runtime/map_vote.py) and, if some of its landmarks are contested, the
    sentence naming them; None for maps that carry none (maps of one run, older maps) and for merged maps."""
    from runtime.map_vote import contested_text, read_vote

    vote = _own_metadata(path, landmark_map, lambda metadata: read_vote(metadata, len(landmark_map)),
                         "its vote record is")
    return {"vote": vote, "contested": None if vote is None else contested_text(vote, landmark_map.positions)}


def _warn_contested(report: dict) -> None:
    for k, m in enumerate(report["maps"]):
        if m["contested"] is not None:
            print(f"p3at fuse: warning: map {k} ({m['robot']}) {m['contested']}", file=sys.stderr)


# identity conflicts printed one per line at most; the rest are counted (all are in --json and the merged map)
MAX_CONFLICT_LINES = 20


def _warn_identity_conflicts(report: dict) -> None:
    conflicts = report.get("identity_conflicts", [])
    if len(conflicts) > MAX_CONFLICT_LINES:
        print(f"p3at fuse: warning: {len(conflicts)} landmark identities placed beyond their covariances apart; the "
              f"first {MAX_CONFLICT_LINES} follow, all are in the merged map's metadata identity_conflicts",
              file=sys.stderr)
    for c in conflicts[:MAX_CONFLICT_LINES]:
        print(f"p3at fuse: warning: {c['robot']} places landmark identity {c['identity']} {c['distance_m']:.2f} m "
              f"from the merged one (d² {c['mahalanobis_d2']:.1f} > gate {c['gate_d2']:.2f}): kept the merged "
              "landmark, not fused with nor added beside it; one of the maps is wrong there", file=sys.stderr)


def _warn_low_confidence(report: dict) -> None:
    for a in report["alignments"]:
        if a["low_confidence"]:
            print(f"p3at fuse: warning: map {a['map2']} -> map {a['map1']} was aligned with low confidence "
                  f"({confidence_text(a['false_alarm_probability'])}; the {a['preset']} preset decides by its support "
                  "count alone)", file=sys.stderr)


def _warn_prior_backed(report: dict) -> None:
    """A found alignment that only its start prior decides (the maps alone are ambiguous or too weak): it is as right
    as the prior, and the user must be able to tell it from one the maps' own evidence carries."""
    for a in report["alignments"]:
        if a["found"] and a.get("rests_on_prior"):
            what = f"map {a['map2']} -> map {a['map1']}{'' if a['used'] else ' (not used)'}"
            print(f"p3at fuse: warning: {rests_on_prior_text(what, a['rests_on_prior'])}", file=sys.stderr)
    for k, m in enumerate(report["maps"]):      # a flagged map's parts, aligned each with its pair's prior
        for part in (m.get("split") or {}).get("parts", []):
            for j, a in part["alignments"].items():
                if part["used"] and a["found"] and a.get("rests_on_prior"):
                    what = f"map {k}'s part {part['part']} its gap -> map {j}"
                    print(f"p3at fuse: warning: {rests_on_prior_text(what, a['rests_on_prior'])}", file=sys.stderr)
