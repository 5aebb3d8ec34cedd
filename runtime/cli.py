"""The ``p3at`` command line: one entry point, one sub-command module per area."""
from __future__ import annotations

import argparse
import importlib
import sys

# Each module here defines ``register(subparsers)``; its handlers return an exit status.
COMMAND_MODULES: tuple[str, ...] = tuple(
    f"runtime.commands.{name}"
    for name in ("robot", "camera", "calib", "features", "slam", "fuse", "scanmatch",
                 "demo", "run", "replay", "review")
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="p3at",
        description="Pioneer P3-AT + STH-MDCS2 stereo: drivers, virtual hardware, visual FastSLAM, map fusion.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
