"""``p3at review FILE.rrd``: read a mission's recording back, summarise it, export the maps it holds."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from runtime.rerun_log import RecordingReadError, read_recording


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "review", help="summarise a mission's .rrd recording and export the maps it holds",
        description="Reads a recording written by 'p3at demo' or 'p3at run' (Rerun 0.41 .rrd), prints the robots, "
                    "the duration, the size of every map and the alignment results, and writes each map it holds "
                    "(the last snapshot of every robot, and the fused map) as a landmark-map .npz and a .ply. "
                    "A recording cut short (a crash, a kill) is read up to its last complete message, and said so.")
    parser.add_argument("recording", type=Path, metavar="FILE.rrd", help="the recording to read")
    parser.add_argument("more", type=Path, nargs="*", metavar="MORE.rrd",
                        help="more files of the same recording (a fleet whose processes each saved their own)")
    parser.add_argument("--export", type=Path, default=None, metavar="DIR",
                        help="where to write the maps (default: FILE-maps/ beside the recording)")
    parser.add_argument("--no-export", action="store_true", help="only print the summary")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(handler=_review)


def review_summary(contents) -> dict:
    """The figures ``review`` prints, from :class:`runtime.rerun_log.RecordingContents`."""
    return {
        "recording": str(contents.path), "robots": contents.robots, "duration": round(contents.duration, 2),
        "maps": {name: len(m) for name, m in sorted(contents.maps.items())},
        "alignments": contents.alignments, "mission_summary": contents.summary,
        "truncated": contents.truncated, "ended": contents.ended,
    }


def _review(args) -> int:
    try:
        contents = read_recording(args.recording, *args.more)
    except RecordingReadError as e:  # not a recording, or damaged before its first message: bad input
        print(f"p3at review: {e}", file=sys.stderr)
        return 2
    summary = review_summary(contents)
    exported: dict[str, list[str]] = {}   # map name -> the files written for it
    if not args.no_export and contents.maps:
        folder = args.export or args.recording.with_name(args.recording.stem + "-maps")
        try:
            for name, m in sorted(contents.maps.items()):
                files = [folder / f"{name}.npz", folder / f"{name}.ply"]
                m.save(files[0])
                m.export_ply(files[1])
                exported[name] = [str(f) for f in files]
        except OSError as e:
            print(f"p3at review: cannot write the maps to {folder}: {e}", file=sys.stderr)
            return 1
    summary["exported"] = exported
    summary["files_written"] = [f for files in exported.values() for f in files]
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    more = f" and {len(args.more)} more file(s)" if args.more else ""
    print(f"Recording {contents.path}{more}: {len(contents.robots)} robot(s) ({', '.join(contents.robots) or 'none'}), "
          f"{contents.duration:.1f} s")
    if contents.truncated:
        print(f"  TRUNCATED recording, {contents.truncated}: what follows is what it held")
    elif not contents.ended:
        print("  the recording has no end-of-stream mark (its writer did not close it): it may end early")
    for name, size in summary["maps"].items():
        print(f"  map {name:<10} {size:6d} landmarks" + (f"  -> {', '.join(exported[name])}"
                                                         if name in exported else ""))
    if not contents.alignments:
        print("  no alignment in this recording")
    for pair, a in sorted(contents.alignments.items()):
        print(_alignment_line(pair, a))
    if contents.summary is None:
        print("  (the mission did not finish: no final summary in the recording)")
    return 0


def _number(a: dict, key: str, digits: int) -> str:
    value = a.get(key)
    return f"{value:.{digits}f}" if isinstance(value, int | float) else "?"


def _alignment_line(pair: str, a: dict) -> str:
    """One alignment as recorded (fields a recording written by another version may lack show as '?')."""
    if not a.get("aligned"):
        return f"  alignment {pair}: none ({a.get('note') or 'maps do not overlap'})"
    names = f"{a['other']} -> {a['reference']}" if "other" in a and "reference" in a else pair
    line = (f"  alignment {names}: tx {_number(a, 'tx', 3)} m, ty {_number(a, 'ty', 3)} m, "
            f"θ {_number(a, 'theta', 4)} rad, {a.get('supports', '?')} supports, {a.get('common', '?')} common")
    if a.get("error_xy") is not None:
        line += f"; error vs truth {_number(a, 'error_xy', 3)} m / {_number(a, 'error_theta', 4)} rad"
    return line
