"""The ``p3at`` command line: one entry point, one sub-command module per area.

A command's module is imported only when that command runs (or its ``--help`` is asked for), so ``p3at --help``
does not pay for numpy, OpenCV and Rerun. Errors reach the user as one line on stderr, never as a traceback:

- exit 2: bad arguments or a bad input file (the project's own ``ValueError``/``LookupError`` subclasses, which
  name the file and the field; a file that does not exist or cannot be read);
- exit 1: another error of the project's (a device that vanished, a robot that does not answer...);
- exit 70: a bug (an exception the project did not raise itself): one line, and ``P3AT_DEBUG=1`` shows the traceback;
- exit 130 on Ctrl-C; a closed pipe (``p3at ... | head``) ends quietly.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from collections.abc import Iterable

# name -> (module defining ``register(subparsers)`` whose handlers return an exit status, one-line summary)
COMMANDS: dict[str, tuple[str, str]] = {
    "robot": ("runtime.commands.robot", "P3-AT over ARCOS: info, drive, and a virtual robot to serve"),
    "camera": ("runtime.commands.camera", "the STH-MDCS2 stereo head: identification, grabbing"),
    "calib": ("runtime.commands.calib", "stereo calibration files: convert, show"),
    "features": ("runtime.commands.features", "stereo features of one image pair -> CSV of matches with 3-D points"),
    "slam": ("runtime.commands.slam", "FastSLAM over landmarks: simulated building, recorded data sets"),
    "fuse": ("runtime.commands.fuse", "align and merge landmark maps of several robots"),
    "scanmatch": ("runtime.commands.scanmatch", "scan-to-scan odometry over a CARMEN laser log (eICP, ICP, PL-ICP)"),
    "demo": ("runtime.commands.demo", "virtual P3-ATs map the simulated building; their maps are fused and scored"),
    "run": ("runtime.commands.run", "the onboard runtime of one robot, real (--robot URL --camera usb) or virtual"),
    "replay": ("runtime.commands.replay", "a sensor log (p3at run/demo --log-sensors) through the pipeline again"),
    "review": ("runtime.commands.review", "summarise a mission's .rrd recording and export the maps it holds"),
}
COMMAND_MODULES: tuple[str, ...] = tuple(module for module, _ in COMMANDS.values())

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_BUG = 70            # sysexits.h EX_SOFTWARE
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141   # what a shell reports for a process ended by SIGPIPE
_PROJECT_PACKAGES = ("drivers", "estimation", "fusion", "mocks", "runtime")


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The whole parser (``commands=None``), or one whose given commands are complete and the rest stubs."""
    parser = argparse.ArgumentParser(
        prog="p3at",
        description="Pioneer P3-AT + STH-MDCS2 stereo: drivers, virtual hardware, visual FastSLAM, map fusion.",
        epilog="'p3at COMMAND --help' describes each command. Units: metres, radians, seconds, Hz.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    loaded = set(COMMANDS) if commands is None else set(commands)
    for name, (module, summary) in COMMANDS.items():
        if name in loaded:
            importlib.import_module(module).register(sub)
        else:
            sub.add_parser(name, help=summary)
    _one_line_usage_errors(parser)
    return parser


class UsageError(Exception):
    """A wrong argument: ``main`` prints it as one line and returns EXIT_BAD_INPUT."""


def _one_line_usage_errors(parser: argparse.ArgumentParser) -> None:
    """A wrong argument is one line naming the command (argparse would print the whole usage block first)."""
    def error(message: str, prog: str = parser.prog) -> None:
        raise UsageError(f"{prog}: {message} (see {prog} --help)")

    parser.error = error
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _one_line_usage_errors(child)


def _command_named(argv: list[str]) -> str | None:
    """The sub-command argv asks for (the first word that names one), if any."""
    for word in argv:
        if word in COMMANDS:
            return word
        if not word.startswith("-"):
            return None
    return None


def _prog_named(parser: argparse.ArgumentParser, argv: list[str]) -> str:
    """The deepest (sub-)command argv names: 'p3at slam simulate' for ['slam', 'simulate', ...]."""
    words = iter(argv)
    while True:
        subparsers = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subparsers:
            return parser.prog
        for word in words:
            if word in subparsers[0].choices:
                parser = subparsers[0].choices[word]
                break
        else:
            return parser.prog


def _is_projects(error: BaseException) -> bool:
    return type(error).__module__.split(".")[0] in _PROJECT_PACKAGES


def error_exit_status(error: Exception) -> int:
    """The exit status a failed command ends with (see the module docstring)."""
    if isinstance(error, OSError) and not _is_projects(error):
        return EXIT_BAD_INPUT if isinstance(error, FileNotFoundError | PermissionError | IsADirectoryError) \
            else EXIT_FAILED
    if not _is_projects(error):
        return EXIT_BUG
    return EXIT_BAD_INPUT if isinstance(error, ValueError | LookupError) else EXIT_FAILED


def _describe(error: Exception) -> str:
    if isinstance(error, OSError) and error.filename is not None and error.strerror:
        return f"{error.filename}: {error.strerror.lower()}"
    text = str(error) or type(error).__name__
    if not _is_projects(error):
        return f"internal error: {type(error).__name__}: {text} (P3AT_DEBUG=1 shows the traceback)"
    return text.splitlines()[0]


class _OneLineWrites:
    """``sys.stderr`` while a command runs: a newline inside one write (a path that holds one, in an error naming
    it) is written as ``\\n``, so that every message stays one line; the newline ending a write is kept. ``print``
    writes its text and its end separately, a logging or warnings record its whole text at once."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        body, end = (text[:-1], "\n") if text.endswith("\n") else (text, "")
        if "\n" in body:
            body = body.replace("\n", "\\n")
        return self._stream.write(body + end)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _command_named(argv)
    prefix = "p3at" if command is None else f"p3at {command}"

    def one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
        # Python's own format is two lines (file:line: Category: message, then the source line): a clamped velocity
        # of `robot drive`, a numpy RuntimeWarning; said as the command's other messages are
        print(f"{prefix}: warning: {message}", file=sys.stderr if file is None else file)

    if os.environ.get("P3AT_DEBUG"):   # a developer's run: Python's own tracebacks and warnings, untouched
        return _main(argv, command)
    stderr, sys.stderr = sys.stderr, _OneLineWrites(sys.stderr)
    showwarning, warnings.showwarning = warnings.showwarning, one_line_warning
    try:
        return _main(argv, command)
    finally:
        warnings.showwarning = showwarning
        if isinstance(sys.stderr, _OneLineWrites):
            sys.stderr = stderr


def _main(argv: list[str], command: str | None) -> int:
    parser = build_parser([] if command is None else [command])
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:   # argparse would name the top parser ('p3at: unrecognized arguments'), not the command
            prog = _prog_named(parser, argv)
            raise UsageError(f"{prog}: unrecognized arguments: {' '.join(extra)} (see {prog} --help)")
        return int(args.handler(args) or 0)
    except UsageError as error:
        print(error, file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # the reader went away (| head): send the rest of our output nowhere and end quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except Exception as error:
        if os.environ.get("P3AT_DEBUG"):
            raise
        prefix = "p3at" if command is None else f"p3at {command}"
        print(f"{prefix}: {_describe(error)}", file=sys.stderr)
        return error_exit_status(error)


if __name__ == "__main__":
    sys.exit(main())
