"""``p3at review FILE.rrd``: read a mission's recording back, summarise it, export the maps it holds.

The recording is read (and its maps exported) in a child process: Rerun's reader (Rust) aborts the whole process
on some damaged messages (a byte flipped in an Arrow schema gave "Timestamp type with unit of <UNKNOWN 16> not
supported" and SIGABRT, found by flipping bytes of a demo's recording; about 3 % of single-bit flips). When it does,
a second child reads the recording again, asking this process before it reads any file whether Rerun reads it
through; this process answers by reading that file in children of its own (runtime/rrd_salvage.ReadingProcesses),
so that the damaged messages are found and left out even when reading them aborts. The recording is then read as
any other damaged one (the DAMAGED line, exit 0). This process does not import Rerun (nor numpy): forking it is safe.
"""
from __future__ import annotations

import multiprocessing
import os
import sys
import tempfile
import threading
from pathlib import Path

from runtime.commands.options import OutputPathError, check_output_folder
from runtime.json_output import json_text
from runtime.rrd_salvage import STOPPED_ON_DAMAGE
from runtime.terminal import printable


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "review", help="summarise a mission's .rrd recording and export the maps it holds",
        description="Reads a recording written by 'p3at demo' or 'p3at run' (Rerun 0.41 .rrd), prints the robots, "
                    "the duration, the size of every map and the alignment results, and writes each map it holds "
                    "(the last snapshot of every robot, and the fused map) as a landmark-map .npz and a .ply. "
                    "A recording cut short (a crash, a kill) is read up to its last complete message, and said so; "
                    "messages Rerun cannot decode (bytes flipped inside them) are skipped, and said so.")
    parser.add_argument("recording", type=Path, metavar="FILE.rrd", help="the recording to read")
    parser.add_argument("more", type=Path, nargs="*", metavar="MORE.rrd",
                        help="more files of the same recording (a fleet whose processes each saved their own)")
    parser.add_argument("--export", type=Path, default=None, metavar="DIR",
                        help="where to write the maps (default: FILE-maps/ beside the recording)")
    parser.add_argument("--no-export", action="store_true", help="only print the summary")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.set_defaults(handler=_review)


def review_summary(contents) -> dict:
    """The figures ``review`` prints, from :class:`runtime.rerun_read.RecordingContents`."""
    return {
        "recording": str(contents.path), "robots": contents.robots, "duration": round(contents.duration, 2),
        "maps": {name: len(m) for name, m in sorted(contents.maps.items())},
        "alignments": contents.alignments, "mission_summary": contents.summary,
        "truncated": contents.truncated, "ended": contents.ended, "damaged": contents.damaged,
    }


# in a reading process started after Rerun's reader killed the first one: asks the parent whether Rerun reads a
# file through (see _reading_process); None: read here
_ask_parent = None


def _not_a_file_name(name: str) -> str | None:
    """Why a map's name in a recording cannot be the stem of a file in the export folder (None: it can). The name
    comes from the recording (an entity path ``maps/NAME``): 'maps/../../x' wrote x.npz two folders above the export
    folder, so a hostile recording could replace any .npz or .ply file the user may write."""
    if name in ("", ".", "..") or "/" in name or "\\" in name or not name.isprintable():
        return f"{printable(name)!r} is not a file name"
    return None


def read_and_export(paths: list[Path], folder: Path | None) -> dict:
    """Runs in the reading process: read the recording, write each map it holds to ``folder`` as .npz and .ply
    (None: none), and return plain data (the caller imports no Rerun): ``{"error": why}`` for a file that is no
    readable recording, ``{"write_error": why}``, or ``{"summary": review_summary(...) + exported files,
    "duration": s}``."""
    from runtime.rerun_read import RecordingReadError, read_recording

    try:
        contents = read_recording(*paths, decodes=_ask_parent)
    except RecordingReadError as e:  # not a recording, or damaged before its first message: bad input
        return {"error": str(e)}
    summary = review_summary(contents)
    exported: dict[str, list[str]] = {}   # map name -> the files written for it
    not_exported: dict[str, str] = {}     # map name -> why it was not written
    if folder is not None and contents.maps:
        try:
            for name, m in sorted(contents.maps.items()):
                if (why := _not_a_file_name(name)) is not None:   # the recording's entity path names the file
                    not_exported[name] = why
                    continue
                files = [folder / f"{name}.npz", folder / f"{name}.ply"]
                m.save(files[0])
                m.export_ply(files[1])
                exported[name] = [str(f) for f in files]
        except OSError as e:
            return {"write_error": f"cannot write the maps to {folder}: {e}"}
    summary["exported"] = exported
    summary["not_exported"] = not_exported
    summary["files_written"] = [f for files in exported.values() for f in files]
    return {"summary": summary, "duration": contents.duration}


def _stderr_to(path: str) -> None:
    """The reading process's standard error goes to ``path`` (a crash's message is read from there)."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND)
    os.dup2(fd, 2)
    os.close(fd)


def _crash_message(text: str) -> str:
    """The reason a Rust panic gives (the line after 'panicked at ...:'), else the last line written."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    for k, line in enumerate(lines[:-1]):
        if "panicked at" in line:
            return lines[k + 1][:200]
    return lines[-1][:200] if lines else "no message"


def _reading_process(conn, err_path: str, reader, paths: list[Path], folder: Path | None,
                     ask_parent: bool = False) -> None:
    """The child's whole life: stderr to ``err_path``, then ``reader(paths, folder)``'s answer (or the exception it
    raised, a bug the parent reports as such) sent over ``conn``. The reader is an argument, not looked up here, so
    that a spawned child (which imports this module afresh) runs the one the parent chose. ``ask_parent``: before
    reading a file, ask the parent over ``conn`` (``("probe", path)``, answered True or False) whether Rerun reads it
    through."""
    global _ask_parent
    _stderr_to(err_path)
    if ask_parent:
        def _ask(candidate: Path) -> bool:
            conn.send(("probe", str(candidate)))
            return bool(conn.recv())

        _ask_parent = _ask
    try:
        answer = ("answer", reader(paths, folder))
    except Exception as e:  # noqa: BLE001 - handed to the parent, which raises it
        answer = ("exception", e)
    try:
        conn.send(answer)
    except Exception as e:  # noqa: BLE001 - an exception that does not pickle: its text, as the bug it is
        raised = answer[1] if answer[0] == "exception" else e
        conn.send(("exception", RuntimeError(f"{type(raised).__name__}: {raised}")))
    conn.close()


def _fork_is_safe() -> bool:
    """Whether this process runs one thread, so that a forked child inherits no lock held mid-way."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return False
    try:
        return len(os.listdir("/proc/self/task")) == 1          # every thread, Rust's and OpenBLAS's included
    except OSError:  # no /proc: Rerun's and OpenBLAS's threads start when they are imported
        return threading.active_count() == 1 and not {"rerun", "numpy"} & sys.modules.keys()


def _decodes_here(candidate: Path) -> bool:
    """Whether Rerun reads ``candidate`` through, read in this process (a reading process of the parent's)."""
    from runtime.rerun_read import _decodes

    return _decodes(candidate)


def _import_reader() -> None:
    """Run by a reading process as it starts: the import (~1 s) then overlaps the reading of the one before it."""
    import runtime.rerun_read  # noqa: F401


def _read_isolated(paths: list[Path], folder: Path | None) -> dict:
    """:func:`read_and_export` in a child process. When Rerun's reader kills it, a second child reads again, every
    file it reads first read through by a child of this process's (:func:`_read_in_child`); a child that dies all the
    same is ``{"error": ...}`` with the reason the first printed. Ctrl-C ends the children at once (the reading one
    would otherwise finish its export first).

    Forked when this process runs a single thread (``p3at review`` itself: it has imported neither Rerun nor numpy),
    so that the child starts at once; otherwise spawned, since a fork copies any lock another thread holds at that
    instant (Rerun starts threads when imported: a caller such as a test process or a notebook)."""
    context = multiprocessing.get_context("fork" if _fork_is_safe() else "spawn")
    with tempfile.NamedTemporaryFile(prefix="p3at-review-", suffix=".err") as err:
        kind, value = _read_in_child(context, err.name, paths, folder, None)
        again = ""
        if kind == "died":       # Rust's abort on a damaged message: read again, each file first tried in a child
            from runtime.rrd_salvage import ReadingProcessError, ReadingProcesses

            try:
                with ReadingProcesses(_decodes_here, context, prepare=_import_reader) as reading:
                    reading.warm()   # their import overlaps the reading child's

                    def probe(candidate: Path) -> bool:  # the one file given is the one the first reader died on
                        return False if paths == [candidate] else reading(candidate)

                    kind, value = _read_in_child(context, err.name, paths, folder, probe)
            except ReadingProcessError as e:
                again = f"; reading it again in separate processes failed: {e}"
        err.seek(0)
        why = _crash_message(err.read().decode("utf-8", "replace"))
        if kind == "died":
            which = str(paths[0]) if len(paths) == 1 else "one of " + ", ".join(map(str, paths))
            return {"error": f"{which}: {STOPPED_ON_DAMAGE} ({why}){again}"}
        if kind == "answer" and value.get("error", "").endswith(STOPPED_ON_DAMAGE):
            value = {"error": f"{value['error']} ({why})"}   # no message to blame: the first reader's reason
    if kind == "exception":
        raise value
    return value


def _read_in_child(context, err_path: str, paths: list[Path], folder: Path | None, probe) -> tuple[str, object]:
    """One reading process: ``("answer", dict)``, ``("exception", e)`` or ``("died", None)``. ``probe``: None, or
    what answers the child's questions ("does Rerun read this file through?") while it reads."""
    receive, send = context.Pipe(duplex=probe is not None)
    child = context.Process(target=_reading_process,
                            args=(send, err_path, read_and_export, paths, folder, probe is not None), daemon=True)
    try:
        child.start()
        send.close()
        while True:
            kind, value = receive.recv()
            if kind != "probe":
                break
            receive.send(probe(Path(value)))
    except EOFError:       # the child died without answering
        child.join()
        return "died", None
    except BaseException:  # Ctrl-C: stop the reading, do not wait for it
        if child.pid is not None:
            child.kill()
            child.join()
        raise
    finally:
        receive.close()
    child.join()
    return kind, value


def _review(args) -> int:
    folder = None if args.no_export else (args.export or args.recording.with_name(args.recording.stem + "-maps"))
    try:
        check_output_folder(folder, "--export")
    except OutputPathError as e:
        hint = "" if args.export else " (the default, beside the recording; give --export DIR or --no-export)"
        print(f"p3at review: {e}{hint}", file=sys.stderr)
        return 2
    for path in (args.recording, *args.more):
        if path.is_dir():   # the reader would say "no such recording" of a folder that is there
            print(f"p3at review: {path}: a folder, not a recording (give the .rrd file in it)", file=sys.stderr)
            return 2
    from runtime.commands.file_kinds import wrong_kind

    for path in (args.recording, *args.more):
        problem = wrong_kind(path, "recording")   # a map or a sensor log: said so, with the command that reads it
        if problem is not None:
            print(f"p3at review: {problem}", file=sys.stderr)
            return 2
    if not args.recording.is_file():   # what the reading process would say first, said before one starts (~1 s)
        from runtime.textfile import not_a_file

        print(f"p3at review: {args.recording}: {not_a_file(args.recording, 'recording')}", file=sys.stderr)
        return 2
    result = _read_isolated([args.recording, *args.more], folder)
    if "error" in result:
        print(f"p3at review: {result['error']}", file=sys.stderr)
        return 2
    if "write_error" in result:
        print(f"p3at review: {result['write_error']}", file=sys.stderr)
        return 1
    summary = result["summary"]
    exported = summary["exported"]
    if args.json:
        print(json_text(summary, indent=2))
        return 0
    more = f" and {len(args.more)} more file(s)" if args.more else ""
    robots = [printable(r) for r in summary["robots"]]
    print(f"Recording {summary['recording']}{more}: {len(robots)} robot(s) ({', '.join(robots) or 'none'}), "
          f"{result['duration']:.1f} s")
    if summary["damaged"]:
        print(f"  DAMAGED recording, {summary['damaged']}")
    if summary["truncated"]:
        print(f"  TRUNCATED recording, {summary['truncated']}: what follows is what it held")
    elif not summary["ended"]:
        print("  the recording has no end-of-stream mark (its writer did not close it): it may end early")
    not_exported = summary.get("not_exported", {})
    for name, size in summary["maps"].items():
        print(f"  map {printable(name):<10} {size:6d} landmarks" + (f"  -> {', '.join(exported[name])}"
                                                                 if name in exported else "")
              + (f"  (not exported: {not_exported[name]})" if name in not_exported else ""))
    run = _dataset_run_line(summary["mission_summary"])   # a data set's run: one robot, nothing to align
    if not summary["alignments"] and run is None:
        print("  no alignment in this recording")
    for pair, a in sorted(summary["alignments"].items()):
        print(_alignment_line(pair, a))
    if run:
        print(run)
    for warning in _run_warnings(summary["mission_summary"]):
        print(f"  WARNING: {warning}")
    if summary["mission_summary"] is None:
        print("  (the mission did not finish: no final summary in the recording)")
    return 0


def _number(a: dict, key: str, digits: int) -> str:
    value = a.get(key)
    return f"{value:.{digits}f}" if isinstance(value, int | float) else "?"


def _alignment_line(pair: str, a: dict) -> str:
    """One alignment as recorded, in the words of the recording's fusion status in the viewer
    (runtime.report.alignment_text: one wording of one state); a figure a recording written by another version
    lacks shows as '?'."""
    from runtime.report import alignment_text

    names = f"{a['other']} -> {a['reference']}" if "other" in a and "reference" in a else pair
    return f"  alignment {names}: {alignment_text(a, missing='?')}"


MAX_WARNINGS_SHOWN = 20


def _run_warnings(run: dict | None) -> list[str]:
    """A data set run's warnings as its command printed them (the summary's ``warnings``), each on one printable line
    (a recording is a file from anywhere: no control character reaches the terminal), at most MAX_WARNINGS_SHOWN."""
    warnings = run.get("warnings") if isinstance(run, dict) else None
    if not isinstance(warnings, list):
        return []
    lines = [printable(w) for w in warnings if isinstance(w, str)]
    if len(lines) > MAX_WARNINGS_SHOWN:
        lines = lines[:MAX_WARNINGS_SHOWN] + [f"… and {len(lines) - MAX_WARNINGS_SHOWN} more in the recording"]
    return lines


def _dataset_run_line(run: dict | None) -> str | None:
    """A data set run's figures (``p3at slam dataset ... --rerun``: its summary holds the run's metrics), the ones
    its own output leads with; None for a mission's recording."""
    if not isinstance(run, dict) or not isinstance(run.get("ate_m"), int | float):
        return None
    line = f"  run: ATE {_number(run, 'ate_m', 3)} m"
    if isinstance(run.get("dead_reckoning_ate_m"), int | float):
        line += f" (dead reckoning {_number(run, 'dead_reckoning_ate_m', 3)} m)"
    if isinstance(run.get("landmark_error_median_m"), int | float):
        line += (f", landmarks {run.get('landmarks', '?')} for {run.get('true_landmarks', '?')} true, median error "
                 f"{_number(run, 'landmark_error_median_m', 3)} m")
    if isinstance(run.get("pose_nees_median"), int | float):
        within = run.get("pose_nees_within_chi2_95")
        line += f", pose NEES median {_number(run, 'pose_nees_median', 1)}" + (
            f" ({100 * within:.0f} % below χ²₃(95 %))" if isinstance(within, int | float) else "")
    return line + ("; smoothed over the whole log" if run.get("smoothed") else "")
