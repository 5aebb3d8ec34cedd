"""The virtual P3-AT's SIP cycle on the wall clock (issue 15: 100 ± 20 ms at the load of a normal demo).

For each scenario it prints the gaps between consecutive SIPs, in ms: median, 95th percentile, max and the share
outside 100 ± 20 ms, twice:

- ``sent``: when the virtual robot's server put each SIP on the wire (``sip_wall_times``, CLOCK_MONOTONIC, which
  is one clock for every process of the machine);
- ``driver``: the stamps of the real ARCOS driver's ``RobotState`` (``P3AT.subscribe``), i.e. what the runtime
  sees. The driver's reader reads in 50 ms windows (``drivers.arcos.robot.READ_TIMEOUT``) and stamps a SIP at the
  end of the window it came in, so this row carries up to 50 ms of the driver's own batching on top of the
  robot's timing.

Scenarios:

- ``alone/thread``: one server thread and its driver in this process, nothing else;
- ``alone/process``: one robot served from its own process (``serve_tcp_process``) and its driver here;
- ``demo/thread`` and ``demo/process``: ``p3at demo --realtime`` (two robots, rendered heads, FastSLAM, Rerun to a
  file), the virtual robots served as threads of the mission's process, or from their own process (the default
  of ``--realtime``);
- ``--busy N`` runs every scenario again beside N ``while True: pass`` processes;

    .venv/bin/python benchmarks/bench_sip_timing.py                         # 30 s alone, 60 s demo, both modes
    .venv/bin/python benchmarks/bench_sip_timing.py --alone 20 --demo 40 --busy 0 2
    .venv/bin/python benchmarks/bench_sip_timing.py --modes thread --demo 0  # one server thread, alone

The first 5 % of each run's gaps (the set-up) are left out. Timings depend on the machine's load: the load average
is printed before each run.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.arcos.robot import P3AT  # noqa: E402
from mocks.world import World  # noqa: E402
from runtime.commands.options import non_negative_float, non_negative_int  # noqa: E402
from runtime.mission import Mission, MissionConfig  # noqa: E402

Row = tuple[str, str, np.ndarray]  # scenario, what, times (s)


def gaps_ms(times) -> np.ndarray:
    t = np.asarray(times, float)
    return np.diff(t[len(t) // 20:]) * 1000.0


def alone(mode: str, seconds: float) -> list[Row]:
    """One virtual robot and its driver, the robot standing still."""
    from mocks.p3at import serve_tcp

    world = World.load()
    received: list[float] = []
    if mode == "thread":
        server = serve_tcp(world, "robot1", port=0)
        sent = server.sip_wall_times
        closer = server
    else:
        from mocks.p3at import RobotSpec, serve_tcp_process

        closer = serve_tcp_process(world, [RobotSpec("robot1")])
        server = closer.servers["robot1"]
    with closer, P3AT(server.url) as driver:
        driver.subscribe(lambda state: received.append(state.stamp))
        driver.connect()
        time.sleep(seconds)
        driver.close()
    sent = server.sip_wall_times
    return [(f"alone/{mode}", "sent", np.array(sent)), (f"alone/{mode}", "driver", np.array(received))]


class _ProbedMission(Mission):
    """The mission, with every driver's SIP stamps recorded."""

    received: dict[str, list[float]]

    def _robot(self, stack, world, index, name, t0):
        setup = super()._robot(stack, world, index, name, t0)
        times = self.received.setdefault(name, [])
        self._drivers[name].subscribe(lambda state: times.append(state.stamp))
        return setup


def demo(mode: str, seconds: float, out: Path) -> list[Row]:
    config = MissionConfig(robots=2, seconds=seconds, seed=0, camera="mock", camera_rate=3.75, out=out,
                           rerun="file", odometry="realistic", realtime=True, robot_process=mode == "process")
    mission = _ProbedMission(config)
    mission.received = {}
    mission.run()
    rows: list[Row] = []
    for name, server in sorted(mission._servers.items()):
        rows.append((f"demo/{mode} {name}", "sent", np.array(server.sip_wall_times)))
        rows.append((f"demo/{mode} {name}", "driver", np.array(mission.received.get(name, []))))
    return rows


def table(rows: list[Row], busy: int) -> None:
    print(f"\n{busy} busy loop(s):")
    print(f"  {'scenario':24s} {'gaps of':7s} {'n':>5s} {'median':>7s} {'p95':>7s} {'max':>7s} {'outside 100±20':>15s}")
    for scenario, what, times in rows:
        g = gaps_ms(times)
        if len(g) < 2:
            print(f"  {scenario:24s} {what:7s} {len(g):5d}   (too few SIPs)")
            continue
        outside = np.mean((g < 80.0) | (g > 120.0))
        print(f"  {scenario:24s} {what:7s} {len(g):5d} {np.median(g):7.1f} {np.percentile(g, 95):7.1f} "
              f"{g.max():7.1f} {outside:15.1%}")


def load() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--alone", type=non_negative_float, default=30.0,
                        help="seconds of the robot-alone runs (0: skip)")
    parser.add_argument("--demo", type=non_negative_float, default=60.0,
                        help="seconds of the realtime demo runs (0: skip)")
    parser.add_argument("--modes", nargs="+", choices=("thread", "process"), default=["thread", "process"])
    parser.add_argument("--busy", type=non_negative_int, nargs="+", default=[0],
                        help="busy-loop processes beside each set")
    args = parser.parse_args()
    for busy in args.busy:
        loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
        try:
            rows: list[Row] = []
            for mode in args.modes:
                if args.alone > 0:
                    print(f"load average {load()}: alone/{mode}, {args.alone:g} s", flush=True)
                    rows += alone(mode, args.alone)
                if args.demo > 0:
                    print(f"load average {load()}: demo/{mode}, {args.demo:g} s", flush=True)
                    with tempfile.TemporaryDirectory() as tmp:
                        rows += demo(mode, args.demo, Path(tmp))
        finally:
            for loop in loops:
                loop.kill()
                loop.wait()
        table(rows, busy)


if __name__ == "__main__":
    main()
