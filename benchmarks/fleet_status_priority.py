"""Statuses sent right behind large maps: how many reach the receiver, with the status at the maps' priority
(Zenoh's DATA) and one step above (DATA_HIGH, what ``ZenohExchange`` sends since session 46).

Run by hand: ``.venv/bin/python benchmarks/fleet_status_priority.py`` (about a minute; run it beside busy processes
to see a loaded machine). Two Zenoh sessions on loopback, configured as the exchange configures them
(``make_config``); one puts ``--maps`` maps of ``--map-bytes`` bytes with ``CongestionControl.DROP``, each followed
at once by a 4-byte status, as ``ZenohExchange.publish`` does; ``--pause`` s between two (the exchange's encoding
takes a few ms). Each trial runs both priorities, one after the other, in an order that alternates.

Why: Zenoh keeps one transmission queue per priority, two batches deep, and drops a DROP message that waits more
than 1 ms for room (50 ms for a fragment). A map larger than a batch (64 kB) fills the queue with its fragments;
a status queued behind them waits with them, and under load the two are lost together. A robot's last map lost
with its status was never asked for (the in-process slow-receiver test failed in CI that way). Prints, per
priority: maps and statuses received of those sent (median and worst over the trials), and the trials that lost
a status.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import zenoh  # noqa: E402

from runtime.commands.options import non_negative_float, positive_int  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.zenoh_exchange import make_config  # noqa: E402

SETTLE = 1.5   # s for the two sessions to connect and declare their routes
DRAIN = 3.0    # s for the last puts to arrive


def endpoint(port: int, role: str) -> str:
    key = "listen" if role == "fusion" else "connect"
    return json.dumps({key: {"endpoints": [f"tcp/127.0.0.1:{port}"]}})


def count(subscriber) -> int:
    received = 0
    while subscriber.try_recv() is not None:
        received += 1
    return received


def trial(priority: zenoh.Priority, maps: int, map_bytes: int, pause: float) -> tuple[int, int]:
    """(maps received, statuses received) of ``maps`` sent each, the status at ``priority``."""
    port = free_port()
    with zenoh.open(make_config(endpoint(port, "fusion"), "fusion")) as node, \
            zenoh.open(make_config(endpoint(port, "robot"), "robot")) as robot:
        map_channel = node.declare_subscriber("bench/map", zenoh.handlers.RingChannel(maps + 1))
        status_channel = node.declare_subscriber("bench/status", zenoh.handlers.RingChannel(maps + 1))
        map_publisher = robot.declare_publisher("bench/map", congestion_control=zenoh.CongestionControl.DROP)
        status_publisher = robot.declare_publisher("bench/status", congestion_control=zenoh.CongestionControl.DROP,
                                                   priority=priority)
        time.sleep(SETTLE)
        payload = bytes(range(256)) * (map_bytes // 256 + 1)
        for k in range(maps):
            map_publisher.put(payload[:map_bytes])
            status_publisher.put(k.to_bytes(4, "little"))
            if pause:
                time.sleep(pause)
        time.sleep(DRAIN)
        return count(map_channel), count(status_channel)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--trials", type=positive_int, default=6)
    p.add_argument("--maps", type=positive_int, default=200, help="maps (and statuses) put per trial")
    p.add_argument("--map-bytes", type=positive_int, default=150_000,
                   help="bytes of each map (a 400-landmark full snapshot is ~150 kB)")
    p.add_argument("--pause", type=non_negative_float, default=0.002, help="s between two publishes")
    args = p.parse_args(argv)
    priorities = {"DATA (the maps')": zenoh.Priority.DATA, "DATA_HIGH": zenoh.Priority.DATA_HIGH}
    results: dict[str, list[tuple[int, int]]] = {name: [] for name in priorities}
    for t in range(args.trials):
        order = list(priorities) if t % 2 == 0 else list(reversed(priorities))
        for name in order:
            results[name].append(trial(priorities[name], args.maps, args.map_bytes, args.pause))
    print(f"{args.trials} trials of {args.maps} maps of {args.map_bytes} B, each followed by its status, "
          f"{args.pause * 1000:g} ms apart")
    print(f"{'status priority':18} {'maps: median':>13} {'worst':>6} {'statuses: median':>17} {'worst':>6} "
          f"{'trials losing a status':>23}")
    for name, rows in results.items():
        maps, statuses = [r[0] for r in rows], [r[1] for r in rows]
        losing = sum(s < args.maps for s in statuses)
        print(f"{name:18} {statistics.median(maps):13g} {min(maps):6d} {statistics.median(statuses):17g} "
              f"{min(statuses):6d} {losing:>17d} of {len(rows)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
