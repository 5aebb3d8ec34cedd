"""``p3at replay LOG``: run a logged robot's raw sensor streams through the pipeline again."""
from __future__ import annotations

import sys
from pathlib import Path

from runtime.commands.options import (
    add_deprecated_alias,
    check_output_apart,
    check_output_file,
    non_negative_int,
    particle_count,
)
from runtime.json_output import json_text
from runtime.replay import onboard_config_from_log, replay_log
from runtime.sensorlog import METADATA_NAME, SensorLog, SensorLogError


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "replay", help="replay a sensor log (p3at run/demo --log-sensors) through the pipeline",
        description="Feeds the SIPs and stereo frames of a sensor log through the front end and FastSLAM, "
                    "deterministically, on a machine with no robot. With the logged settings (the default) it "
                    "rebuilds the live run's map; change --particles, --seed or --every-frame to see what other "
                    "settings give.")
    parser.add_argument("log", type=Path, metavar="LOG",
                        help="a sensor log: the folder of MCAP segments that --log-sensors writes, or one .mcap file")
    parser.add_argument("--out", type=Path, default=None, metavar="MAP.npz", help="write the resulting map here")
    parser.add_argument("--particles", type=particle_count, default=None,
                        help="FastSLAM particles (default: as logged)")
    parser.add_argument("--seed", type=non_negative_int, default=None,
                        help="filter seed, a whole number >= 0 (default: as logged)")
    parser.add_argument("--fastslam", type=int, choices=(1, 2), default=None,
                        help="FastSLAM 1.0 or 2.0 (default: as logged)")
    add_deprecated_alias(parser, "--version", "--fastslam")  # the old spelling, for one release: hidden, warns
    parser.add_argument("--every-frame", action="store_true",
                        help="process every logged frame, not only those the live pipeline had time for")
    parser.add_argument("--allow-truncated", action="store_true",
                        help="read a .mcap segment that ends early (copied or written in part) up to its last "
                             "complete chunk, with a warning (a crash's .mcap.part always is); default: refuse it")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(handler=_replay)


def _check_replayable(log: SensorLog, path) -> None:
    """A log replay can use: it holds messages and the settings record p3at's logger writes first in every
    segment. Another tool's ROS 2 bag (or a log cut before its first chunk) gave '0 frames, 0 landmarks', exit 0."""
    if not log.counts:
        raise SensorLogError(f"{path}: holds no complete message (cut before its first chunk was written?)")
    if not log.metadata:
        topics = sorted(log.counts)
        shown = ", ".join(topics[:4]) + (f" and {len(topics) - 4} more" if len(topics) > 4 else "")
        raise SensorLogError(f"{path}: not a p3at sensor log (no '{METADATA_NAME}' settings record; its topics: "
                             f"{shown}): replay reads the logs that p3at run/demo --log-sensors write")


def _replay(args) -> int:
    check_output_file(args.out)   # an OutputPathError is one line and exit 2 (runtime/cli.py), before the replay
    log_path = Path(args.log)     # the map must not replace a segment: a folder's, or the one file given
    check_output_apart(args.out, files={"sensor log": None if log_path.is_dir() else log_path},
                       folders={"sensor log": log_path if log_path.is_dir() else None})
    from runtime.commands.file_kinds import wrong_kind

    problem = None if log_path.is_dir() else wrong_kind(log_path, "sensor log")
    if problem is not None:   # a map or a recording: said so, with the command that reads it
        print(f"p3at replay: {problem}", file=sys.stderr)
        return 2
    try:
        log = SensorLog(args.log, allow_truncated=args.allow_truncated)
        _check_replayable(log, args.log)
        for warning in log.warnings:
            print(f"p3at replay: warning: {warning}", file=sys.stderr)
        overrides = {} if args.fastslam is None else {"version": args.fastslam}
        config = onboard_config_from_log(log, particles=args.particles, seed=args.seed, fastslam_overrides=overrides)
        result = replay_log(log, config, every_frame=args.every_frame)
        if args.out is not None:
            result.landmark_map.save(args.out)
        if result.missing_frames:
            print(f"p3at replay: warning: {result.missing_frames} frames the live run processed are not in the log "
                  "(dropped by the log writer or cut by a crash): this map differs from the live one", file=sys.stderr)
    except SensorLogError as e:  # a bad file: one line, exit 2
        print(f"p3at replay: {e}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as e:
        print(f"p3at replay: {e}", file=sys.stderr)
        return 1
    summary = {
        "robot": result.robot, "frames": result.frames, "skipped_without_odometry": result.skipped_without_odometry,
        "landmarks": len(result.landmark_map), "final_pose": [round(float(v), 4) for v in result.final_pose],
        "log_seconds": round(result.log_span, 2), "replay_seconds": round(result.seconds, 2),
        "times_real_time": round(result.speed, 2),
        "ms_per_frame": {k: round(1000 * v / max(1, result.frames), 2) for k, v in result.stage_seconds.items()},
        "particles": config.fastslam.n_particles, "seed": config.seed, "missing_frames": result.missing_frames,
        "map": None if args.out is None else str(args.out),
    }
    if args.json:
        print(json_text(summary, indent=2))
    else:
        print(f"Replayed {args.log}: {result.robot}, {result.frames} frames over {result.log_span:.1f} s of log in "
              f"{result.seconds:.1f} s ({result.speed:.1f}x real time), {config.fastslam.n_particles} particles")
        print(f"  map: {len(result.landmark_map)} landmarks; final pose {summary['final_pose']}"
              + (f"; written to {args.out}" if args.out else ""))
        print("  ms per frame: " + ", ".join(f"{k} {v:.1f}" for k, v in summary["ms_per_frame"].items()))
    return 0
