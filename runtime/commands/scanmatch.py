"""``p3at scanmatch LOG``: scan-to-scan odometry over a CARMEN laser log, with its error against the log's poses.

Exit status: 0 done; 1 the matching failed; 2 bad arguments or a bad log file (one line on stderr).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimation.scanmatch import METHODS, LogFormatError, MatchConfig, ScanMatchError, read_laser_log
from estimation.scanmatch.carmen import TruncatedLogError
from estimation.scanmatch.evaluate import GUESSES, SUCCESS_ROTATION, SUCCESS_TRANSLATION, scan_odometry
from runtime.commands.options import add_deprecated_alias, positive_float, positive_int, whole_number_at_least
from runtime.json_output import json_text

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "scanmatch", help="scan-to-scan odometry over a CARMEN laser log (eICP, ICP, PL-ICP)",
        description="Match every scan k apart in a CARMEN log (FLASER lines, plain or .gz) against the previous "
                    "one, chain the relative poses, and print the error against the log's reference poses "
                    f"(a link succeeds within {SUCCESS_TRANSLATION:.2f} m and {np.degrees(SUCCESS_ROTATION):.0f}°).")
    parser.add_argument("log", type=Path, metavar="LOG", help="CARMEN log file")
    parser.add_argument("--matcher", choices=tuple(METHODS), default="eicp",
                        help="eicp (extended ICP), eicp-mesh (rigid-mesh eICP), icp, plicp (default: eicp)")
    parser.add_argument("--step", type=positive_int, default=1, metavar="K",
                        help="match scan i+K against scan i (default 1)")
    parser.add_argument("--guess", choices=GUESSES, default="identity",
                        help="initial guess of each link: identity (default), constant-velocity (the previous "
                             "link), or reference (the log's relative pose: the matcher's accuracy alone)")
    parser.add_argument("--max-distance", type=positive_float, default=MatchConfig.max_distance, metavar="M",
                        help=f"correspondence gate in metres (default {MatchConfig.max_distance})")
    parser.add_argument("--limit", type=whole_number_at_least(2), default=None, metavar="N",
                        help="use only the first N scans")
    parser.add_argument("--allow-truncated", action="store_true",
                        help="if the log is damaged part-way (a corrupted or cut .gz, a malformed line), use the "
                             "readings before the damage (and say so) instead of refusing the log")
    parser.add_argument("--json", action="store_true", help="print the summary (and trajectory) as JSON")
    add_deprecated_alias(parser, "--method", "--matcher")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    try:
        readings = read_laser_log(args.log, limit=args.limit)
    except TruncatedLogError as exc:
        if not args.allow_truncated or len(exc.readings) < 2:
            usable = len(exc.readings) >= 2 and not args.allow_truncated
            hint = "; --allow-truncated uses the readings before the damage" if usable else ""
            print(f"p3at scanmatch: {exc}{hint}", file=sys.stderr)
            return EXIT_BAD_INPUT
        readings = exc.readings
        print(f"p3at scanmatch: warning: {exc}; using those {len(readings)} readings", file=sys.stderr)
    except (LogFormatError, OSError) as exc:
        print(f"p3at scanmatch: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if len(readings) <= args.step:   # the arguments ask for more than the log holds: the user's, exit 2 (was 1)
        if len(readings) > 1:
            limit = f" (--limit {args.limit})" if args.limit else ""
            why = (f"--step {args.step}: the log{limit} has {len(readings)} scans, too few for one link (a step of "
                   f"at most {len(readings) - 1})")
        else:
            why = f"{args.log}: {len(readings)} scan, too few for one link"
        print(f"p3at scanmatch: {why}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        scans = [reading.scan() for reading in readings]
        poses = np.array([reading.pose for reading in readings])
        config = MatchConfig(max_distance=args.max_distance)
        odometry = scan_odometry(scans, poses, args.matcher, args.step, args.guess, config)
    except ScanMatchError as exc:
        print(f"p3at scanmatch: {exc}", file=sys.stderr)
        return EXIT_FAILED
    summary = {"log": str(args.log), "matcher": args.matcher, "step": args.step, "guess": args.guess,
               **odometry.summary(poses)}
    if args.json:
        summary["config"] = config.to_dict()
        summary["trajectory"] = odometry.trajectory.tolist()
        summary["reference"] = poses[odometry.indices].tolist()
        print(json_text(summary, indent=2))
        return 0
    print(f"{args.log}: {summary['links']} links, matcher {args.matcher}, step {args.step}, guess {args.guess}")
    print(f"  converged {100 * summary['converged_share']:.1f} %, within {SUCCESS_TRANSLATION:.2f} m / "
          f"{np.degrees(SUCCESS_ROTATION):.0f}° {100 * summary['success_share']:.1f} %")
    print(f"  per link: median error {100 * summary['median_translation_error_m']:.1f} cm, "
          f"{summary['median_rotation_error_deg']:.2f}°; {summary['mean_iterations']:.1f} iterations, "
          f"{summary['mean_time_ms']:.2f} ms")
    print(f"  end point after {summary['path_length_m']:.1f} m: {summary['end_translation_error_m']:.2f} m, "
          f"{summary['end_rotation_error_deg']:.1f}°")
    return 0
