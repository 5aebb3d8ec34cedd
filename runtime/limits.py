"""Limits and spellings that the command line and the runtime's modules share (stdlib only, imports nothing).

The CLI layer (``runtime.commands.options``) checks arguments against them; the runtime's modules check what
files and sinks ask for against the same values (``runtime.sensorlog`` a log's settings, ``runtime.rerun_sink``
a ``--rerun`` sink). They live here, not in the CLI layer, so that no runtime module imports the command line,
and so that ``p3at --help`` loads nothing heavy for them.
"""
from __future__ import annotations

# FastSLAM particles: memory grows with them (~15 kB each with a handful of landmarks, more with a building's worth:
# 100,000 took 1.6 GB and 124 s for 20 s of a small log; --particles 100000000 was killed by the kernel at 22 GB).
# `--particles` takes at most this, and a sensor log's settings may ask replay for at most this.
MAX_PARTICLES = 10_000

# what a --rerun sink is taken as a URL for: the one spelling of them (the CLI's checks, and
# runtime/rerun_sink.py's open_recording)
RERUN_URL_PREFIXES = ("rerun://", "rerun+http://", "rerun+https://", "http://")

# a mission's --camera and --motion (runtime/mission_cli.py offers them, runtime/mission.py's MissionConfig checks them)
CAMERAS = ("mock", "synthetic", "usb")
MOTIONS = ("route", "explore", "none")

__all__ = ["CAMERAS", "MAX_PARTICLES", "MOTIONS", "RERUN_URL_PREFIXES"]
