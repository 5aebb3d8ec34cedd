"""Option helpers every command shares: number types that refuse nonsense, and deprecated spellings.

The number types are argparse ``type=`` callables: ``--max-distance nan`` or ``--seconds -1`` end in argparse's
usage error (exit status 2) naming the option, before anything runs.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from estimation.fileio import special_file_kind  # stdlib only: `p3at --help` stays light
from runtime.limits import MAX_PARTICLES, RERUN_URL_PREFIXES  # shared with the runtime's modules; stdlib only


def float_where(text: str, domain: str, inside) -> float:
    """``text`` as a finite float for which ``inside(value)`` holds; else the error says ``domain`` (for a type
    with one user, e.g. ``--camera-latency`` in [0, 1))."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and inside(value)):
        raise argparse.ArgumentTypeError(f"expected {domain}, not {text!r}")
    return value


def finite_float(text: str) -> float:
    """A finite real number."""
    return float_where(text, "a finite number", lambda value: True)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    return float_where(text, "a finite number > 0", lambda value: value > 0)


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    return float_where(text, "a finite number >= 0", lambda value: value >= 0)


def start_sigmas(text: str) -> tuple[float, float]:
    """'SIGMA_XY,SIGMA_YAW': two positive numbers (m, rad)."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 2 or not all(math.isfinite(v) and 0 < v <= 1e6 for v in values):
        raise argparse.ArgumentTypeError(f"expected SIGMA_XY,SIGMA_YAW, two positive numbers (m, rad) up to 1e6, not "
                                         f"{text!r}")
    return values


def whole_number_where(text: str, domain: str, inside) -> int:
    """``text`` as an int for which ``inside(value)`` holds; else the error says ``domain``."""
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not inside(value):
        raise argparse.ArgumentTypeError(f"expected {domain}, not {text!r}")
    return value


def whole_number_at_least(low: int, name: str | None = None):
    """The argparse type of a whole number >= ``low``; ``name`` (default ``whole_number_at_least_<low>``) is
    the type's ``__name__``, which tests/test_cli_consistency.py compares across commands."""

    def parse(text: str) -> int:
        return whole_number_where(text, f"a whole number >= {low}", lambda value: value >= low)

    parse.__name__ = parse.__qualname__ = name or f"whole_number_at_least_{low}"
    parse.__doc__ = f"A whole number >= {low}."
    return parse


positive_int = whole_number_at_least(1, name="positive_int")
# seeds (numpy's generators refuse negative ones) and counts where 0 is documented as "none" or "all"
non_negative_int = whole_number_at_least(0, name="non_negative_int")

# --time-scale of the virtual robots on the wall clock (robot serve, run/demo --realtime): beyond this the robot's
# physics, run to the wall clock's simulated time, falls behind for good (1e9 s per wall second: `robot serve
# --duration 1` never ended; run --time-scale 1e308: 'no ARCOS handshake after 10 tries', exit 1)
MAX_TIME_SCALE = 1000.0


def time_scale_problem(time_scale: float) -> str | None:
    """Why a --time-scale cannot run (None when it can)."""
    if time_scale > MAX_TIME_SCALE:
        return (f"--time-scale {time_scale:g}: at most {MAX_TIME_SCALE:g} simulated seconds per wall second (the "
                "virtual robot's physics could not keep up)")
    return None


def particle_count(text: str) -> int:
    """A whole number of FastSLAM particles in 1..MAX_PARTICLES."""
    return whole_number_where(text, f"a whole number >= 1 and at most {MAX_PARTICLES} (particles)",
                              lambda value: 1 <= value <= MAX_PARTICLES)


def recording_id(text: str) -> str:
    """A Rerun recording id shared by a fleet's processes: printable text of 1 to 256 characters. An empty one fell
    through to a new random id without a word, and the files no longer read as one recording."""
    if not text.strip() or len(text) > 256 or not text.isprintable():
        raise argparse.ArgumentTypeError(f"invalid value {text!r}: a recording id is printable text of 1 to 256 "
                                         "characters, the same in every process of the fleet")
    return text


class _DeprecatedAlias(argparse.Action):
    """Stores into the new option's destination and says, once, which spelling to use instead."""

    def __init__(self, option_strings, dest, new_option: str, **kwargs) -> None:
        self.new_option = new_option
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"{parser.prog}: {option_string} is deprecated and will go in the next release; "
              f"use {self.new_option}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def add_deprecated_alias(parser: argparse.ArgumentParser, old: str, new: str, **kwargs) -> None:
    """Accept ``old`` as a hidden spelling of the already added option ``new`` (same destination and type)."""
    action = next(a for a in parser._actions if new in a.option_strings)
    parser.add_argument(old, action=_DeprecatedAlias, new_option=new, dest=action.dest, type=action.type,
                        choices=action.choices, metavar=action.metavar, help=argparse.SUPPRESS, **kwargs)


def deprecated_options(parser: argparse.ArgumentParser) -> list[str]:
    """The hidden deprecated spellings a parser accepts."""
    return [s for a in parser._actions if isinstance(a, _DeprecatedAlias) for s in a.option_strings]


class OutputPathError(ValueError):
    """An output path no file (or folder) can be written at: the command says so before it does its work."""


def _writable_ancestor(path: Path) -> str | None:
    """Why no file can be created under ``path``'s folder (None when one can): the nearest folder that exists
    must be writable (the writers create the missing folders below it)."""
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        return f"{folder} is not a folder"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"cannot write in {folder} (permission denied)"
    return None


def check_output_file(path: str | os.PathLike | None, option: str = "--out") -> None:
    """Raise :class:`OutputPathError` when ``path`` cannot take a file: a folder is there, a file is where a folder
    must be, or the folder is not writable. Commands call it before their work, so that a long run does not end
    on an output it cannot write (the write itself stays atomic: a temporary file renamed over the target)."""
    if path is None:
        return
    target = Path(path)
    if target.is_dir():
        raise OutputPathError(f"{option} {path}: is a folder; give a file name")
    kind = special_file_kind(target)
    if kind is not None:   # the atomic write renames a new file over it: a FIFO, or /dev/null as root, would go
        raise OutputPathError(f"{option} {path}: is {kind}, not a file (a file is written beside it and renamed "
                              "over it); give a file name")
    why = _writable_ancestor(target)
    if why is not None:
        raise OutputPathError(f"{option} {path}: {why}")


def check_output_folder(path: str | os.PathLike | None, option: str = "--out") -> None:
    """As :func:`check_output_file` for an output folder: a file there, or a folder that cannot be written."""
    if path is None:
        return
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise OutputPathError(f"{option} {path}: a file is there; give a folder")
    why = _writable_ancestor(target / "x") if target.is_dir() else _writable_ancestor(target)
    if why is not None:
        raise OutputPathError(f"{option} {path}: {why}")


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one file: any spelling of it (``..``, a relative path), a symbolic link to it, or a
    hard link (both exist: ``os.path.samefile``); a path that does not exist (yet) by its resolved spelling."""
    try:
        return os.path.samefile(a, b)
    except OSError:       # one of them does not exist (yet): no inode to compare
        return os.path.realpath(a) == os.path.realpath(b)


def check_output_apart(path: str | os.PathLike | None, option: str = "--out", *, files: dict | None = None,
                       folders: dict | None = None) -> None:
    """Raise :class:`OutputPathError` when the output ``path`` names one of the command's input ``files`` ({option or
    role: path}; :func:`same_file`) or is, or lies inside, one of its input ``folders`` (a data set, whose tables a
    file written there could replace; links and ``..`` resolved): the write would destroy what the command reads.
    The one check of outputs against inputs: the commands' (``fuse``, ``slam``) and the benchmarks'
    (``benchmarks/output_paths.py``)."""
    if path is None:
        return
    for role, given in (files or {}).items():
        if given is not None and same_file(path, given):
            raise OutputPathError(f"{option} {path} is the {role} file {given}: writing it would replace it; give "
                                  "another file")
    target = Path(os.path.realpath(path))
    for role, given in (folders or {}).items():
        if given is not None and target.is_relative_to(Path(os.path.realpath(given))):
            raise OutputPathError(f"{option} {path} is inside the {role} folder {given}: a file written there could "
                                  "replace one of its files; write it elsewhere")


RERUN_KEYWORDS = ("file", "spawn", "none")   # --rerun of demo, run and fuse --live, beside FILE.rrd and a URL


def rerun_sink_problem(sink: str | None, keywords: tuple[str, ...] = ()) -> str | None:
    """Why the ``--rerun`` sink cannot serve, in one line naming it (None when it can), said before any work: one of
    the command's ``keywords`` (e.g. file, spawn, none), a URL Rerun takes (:func:`rerun_url_problem`), or a
    ``FILE.rrd`` a file can be written at. Any other word was saved to a file of that name (``--rerun foo``, a
    mistyped keyword, made a file 'foo'; ``--rerun DIR`` ended in Rerun's warnings and exit 1)."""
    if sink is None or sink in keywords:
        return None
    if sink.startswith(RERUN_URL_PREFIXES):   # a URL Rerun takes, and a viewer that answers there
        from runtime.rerun_sink import viewer_url_problem

        return rerun_url_problem(sink) or viewer_url_problem(sink)
    if not sink.endswith(".rrd"):
        return f"--rerun {sink}: give {', '.join(keywords + ('FILE.rrd',))} or a rerun+http:// URL"
    try:
        check_output_file(sink, "--rerun")
    except OutputPathError as e:
        return str(e)
    return None


def rerun_url_problem(sink: str | None) -> str | None:
    """Why Rerun refuses the ``--rerun`` URL ``sink``, in one line naming the option (None when ``sink`` is no URL,
    or one Rerun takes), found by Rerun's own parser without connecting to anything: a command says it before it
    starts, not when its recording opens (``demo``/``run`` ended in exit 1, ``mission failed: --rerun ...``)."""
    if sink is None or not sink.startswith(RERUN_URL_PREFIXES):
        return None
    from runtime.rerun_sdk import rr  # runtime/rerun_sdk.py is the one module that imports rerun

    try:
        rr.GrpcSink(sink)   # parses the URL as connect_grpc does; opens no connection
    except RuntimeError as e:   # Rerun's 'invalid endpoint "...": invalid IPv4 address'
        return f"--rerun {sink}: {e}"
    return None
