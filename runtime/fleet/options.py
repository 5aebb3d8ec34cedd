"""The fleet's command-line options, shared by ``p3at run``, ``p3at demo`` and ``p3at fuse --live``.

Importing this module does not import zenoh: the Zenoh exchange is opened only when asked for.
"""
from __future__ import annotations

import argparse

DEFAULT_FLEET = "p3at"


def add_exchange_arguments(parser: argparse.ArgumentParser, default: str = "inprocess") -> None:
    parser.add_argument("--exchange", default=default, metavar="SPEC",
                        help="map exchange: inprocess (one process), zenoh (loopback defaults: the fusion node "
                             "listens on tcp/127.0.0.1:7447, robots connect to it) or zenoh:CONFIG (a Zenoh JSON5 "
                             f"file with your endpoints, TLS, access control; see docs/fleet.md; default {default})")
    parser.add_argument("--fleet", default=DEFAULT_FLEET, metavar="NAME",
                        help=f"fleet namespace of the Zenoh keys p3at/NAME/... (default {DEFAULT_FLEET})")


def parse_exchange_spec(spec: str) -> tuple[str, str | None]:
    """``inprocess``, ``zenoh`` or ``zenoh:CONFIG`` (a JSON5 file, or inline JSON5 starting with ``{``)."""
    kind, _, config = spec.partition(":")
    if kind not in ("inprocess", "zenoh") or (kind == "inprocess" and config):
        raise ValueError(f"--exchange must be inprocess, zenoh or zenoh:CONFIG, not {spec!r}")
    return kind, config or None


def open_exchange(spec: str, fleet: str, role: str, on_event=None, on_update=None):
    """The exchange a spec names, or None for ``inprocess`` (the mission's own); ValueError for a bad spec."""
    kind, config = parse_exchange_spec(spec)
    if kind == "inprocess":
        return None
    from runtime.fleet.zenoh_exchange import ZenohExchange

    return ZenohExchange(fleet, config, role, on_event=on_event, on_update=on_update)


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    """The options ``p3at fuse --live`` adds (beside --exchange and --fleet)."""
    from runtime.commands.options import non_negative_float, positive_float

    parser.add_argument("--interval", type=positive_float, default=10.0, metavar="S",
                        help="--live: fuse at least every S seconds while maps change, and confirm a found "
                             "alignment S seconds later: seconds of the robots' mission time, the stamps of their "
                             "maps (default 10)")
    parser.add_argument("--min-period", type=non_negative_float, default=1.0, metavar="S",
                        help="--live: fuse new maps once S seconds have passed since the last fusion, of the "
                             "robots' mission time or of the node's, whichever has passed more (default 1)")
    parser.add_argument("--seconds", type=non_negative_float, default=0.0, metavar="S",
                        help="--live: stop after S seconds (default 0: until Ctrl-C or SIGTERM)")
    parser.add_argument("--rerun", default="none", metavar="SINK",
                        help="--live: file (fusion.rrd beside --out), spawn, none (default), FILE.rrd or a "
                             "rerun+http:// URL")
