"""The simulated-time demo's wall time and real-time factor, per stage, idle and beside busy-loop processes.

Runs ``p3at demo``'s mission (two virtual P3-ATs, rendered heads through the Videre driver, FastSLAM, fusion) on
the lockstep clock (``mocks.simclock``) and prints, for each run, the wall seconds, the real-time factor
(simulated / wall seconds) and where the wall time went: the seconds each kind of participant held the baton
(e.g. ``camera`` = rendering and delivering frames, ``slam`` = front end + FastSLAM), the seconds time waited
for a quiescence predicate (SIPs on their way through the ARCOS driver's reader thread, which reads in 50 ms
windows), and the rest (the coordinator's hand-overs and thread wake-ups). A stage's factor is simulated
seconds / its wall seconds: how much faster than real time that stage alone would let the mission run.

It also checks that the maps of the runs are identical, array for array (the point of simulated time).

``--sip-gaps S`` instead runs the demo for S seconds on the wall clock (``--realtime``) and prints the gaps
between the virtual P3-ATs' SIPs as sent (wall time): the SIP cycle should stay within 100 ± 20 ms.

    .venv/bin/python benchmarks/bench_sim_time.py                       # 20 s demo, idle then 2 busy loops
    .venv/bin/python benchmarks/bench_sim_time.py --seconds 10 --camera synthetic --camera-rate 10 --busy 0 2
    .venv/bin/python benchmarks/bench_sim_time.py --sip-gaps 60                 # the realtime demo's SIP cycle
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

from runtime.commands.options import non_negative_int, positive_float, positive_int  # noqa: E402
from runtime.mission import Mission, MissionConfig  # noqa: E402


def run(args: argparse.Namespace, out: Path, busy: int) -> tuple[dict, dict[str, float], float]:
    loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        config = MissionConfig(robots=2, seconds=args.seconds, seed=args.seed, camera=args.camera,
                               camera_rate=args.camera_rate, particles=args.particles, out=out, rerun="none",
                               odometry="realistic", fusion_interval=args.seconds / 2)
        mission = Mission(config)
        start = time.monotonic()
        result = mission.run()
        total = time.monotonic() - start
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    clock = mission.clock
    stages: dict[str, float] = {}
    for name, seconds in clock.participant_wall.items():
        stage = name.split(":")[0]
        stages[stage] = stages.get(stage, 0.0) + seconds
    stages["SIPs on their way (driver reader)"] = sum(clock.quiescence_wall.values())
    return result.summary, stages, total


def sip_gaps(args: argparse.Namespace, out: Path) -> None:
    config = MissionConfig(robots=2, seconds=args.sip_gaps, seed=args.seed, camera=args.camera,
                           camera_rate=args.camera_rate, particles=args.particles, out=out, rerun="file",
                           odometry="realistic", realtime=True)
    mission = Mission(config)
    mission.run()
    for name, server in mission._servers.items():
        times = np.array(server.sip_wall_times)
        gaps = np.diff(times[len(times) // 20:]) * 1000.0  # the mission, not the set-up
        outside = np.mean((gaps < 80.0) | (gaps > 120.0))
        print(f"{name}: {len(gaps)} SIP gaps (ms): median {np.median(gaps):.1f}, 5 % {np.percentile(gaps, 5):.1f}, "
              f"95 % {np.percentile(gaps, 95):.1f}, 99 % {np.percentile(gaps, 99):.1f}, max {gaps.max():.1f}; "
              f"outside 100 ± 20: {outside:.1%}")


def same_maps(a: Path, b: Path) -> bool:
    for path in sorted(a.glob("*.npz")):
        with np.load(path) as x, np.load(b / path.name) as y:
            if x.files != y.files or not all(np.array_equal(x[k], y[k]) for k in x.files):
                return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=positive_float, default=20.0, help="simulated seconds (default 20)")
    parser.add_argument("--camera", choices=("mock", "synthetic"), default="mock")
    parser.add_argument("--camera-rate", type=positive_float, default=3.75)
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--busy", type=non_negative_int, nargs="+", default=[0, 2],
                        help="busy-loop processes beside each run (default: 0 then 2)")
    parser.add_argument("--sip-gaps", type=positive_float, default=None, metavar="S",
                        help="run the demo S s on the wall clock and print the SIP gaps instead")
    args = parser.parse_args()
    if args.sip_gaps is not None:
        with open("/proc/loadavg") as f:
            print(f"load average before: {f.read().split()[:3]}; realtime demo, {args.sip_gaps:g} s")
        with tempfile.TemporaryDirectory() as tmp:
            sip_gaps(args, Path(tmp))
        return
    with open("/proc/loadavg") as f:
        print(f"load average before: {f.read().split()[:3]}; {args.seconds:g} s simulated, camera {args.camera} "
              f"{args.camera_rate:g} Hz, {args.particles} particles, seed {args.seed}")
    outs = []
    with tempfile.TemporaryDirectory() as tmp:
        for busy in args.busy:
            out = Path(tmp) / f"busy{busy}"
            summary, stages, total = run(args, out, busy)
            outs.append(out)
            sim, wall = summary["sim_seconds"], summary["wall_seconds"]
            print(f"\n{busy} busy loop(s): {sim:.1f} s simulated in {wall:.1f} s of wall time "
                  f"(real-time factor {sim / wall:.2f}; {total:.1f} s with setup and shutdown)")
            print(f"  {'stage':38s} {'wall s':>8s} {'share':>6s} {'x real time':>11s}")
            rest = wall - sum(stages.values())
            for stage, seconds in sorted(stages.items(), key=lambda kv: -kv[1]) + [("hand-overs, wake-ups", rest)]:
                factor = sim / seconds if seconds > 0 else float("inf")
                print(f"  {stage:38s} {seconds:8.2f} {seconds / wall:6.0%} {factor:11.1f}")
            pair = summary["fusion"]["pairs"][0] if summary["fusion"] and summary["fusion"]["pairs"] else None
            figures = ", ".join(f"{n}: {r['landmarks']} landmarks, error {r['final_position_error']:.3f} m"
                                for n, r in summary["robots"].items())
            print(f"  {figures}" + (f"; alignment error {pair['error_xy']:.3f} m / {pair['error_theta']:.4f} rad"
                                     if pair and pair["error_xy"] is not None else ""))
        if len(outs) > 1:
            print("\nmaps identical across the runs:", all(same_maps(outs[0], o) for o in outs[1:]))


if __name__ == "__main__":
    main()
