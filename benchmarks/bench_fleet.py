"""A fleet over Zenoh on this machine: fleets of 2, 4, 8 and 16 synthetic robots and one fusion node.

Run by hand: ``.venv/bin/python benchmarks/bench_fleet.py`` (about a minute per fleet size; ``--sizes 2 4``
for fewer). The robots are synthetic map publishers (runtime/fleet/synthetic.py: growing maps of up to a few
hundred landmarks with 64-D descriptors, a few landmarks re-observed per update), spread over at most
``--publishers`` processes, one Zenoh session per robot; the fusion node is this process, on loopback.

Prints per fleet size:
- bytes/s per robot on the wire: deltas with a full snapshot every 10th update (what the fleet sends), against
  full snapshots only (the same maps, encoded whole), and the status messages;
- latency from a robot's map update (its wall-clock stamp) to the fused map that holds it (published by the
  node): median and 90th percentile, over every robot update that made it into a fusion;
- the fusion node's CPU: this process's CPU time over the run's wall time (receive, decode, fuse, publish),
  the median wall time of one fusion, and the node's CPU time per fusion (less sensitive to the machine's load).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.commands.options import positive_float, positive_int  # noqa: E402
from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402


def run_fleet(size: int, steps: int, period: float, publishers: int) -> dict:
    port, fleet = free_port(), f"bench{size}x{os.getpid()}"
    latencies: list[float] = []
    seen: dict[str, int] = {}
    node_box: list[FusionNode] = []
    exchange = ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion",
                             on_update=lambda robot: node_box and node_box[0].notify(robot))

    def on_report(report) -> None:
        now = time.time()
        for robot, (sequence, stamp) in node.sources.items():
            if seen.get(robot) != sequence:
                seen[robot] = sequence
                latencies.append(now - stamp)

    node = FusionNode(exchange, FusionNodeConfig(interval=1.0, min_period=0.0), on_report=on_report)
    node_box.append(node)
    names = [f"robot{k + 1}" for k in range(size)]
    groups = np.array_split(np.arange(size), min(size, publishers))
    config = json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})
    processes = [subprocess.Popen(
        [sys.executable, "-m", "runtime.fleet.synthetic", "--names", ",".join(names[k] for k in g),
         "--first-index", str(g[0]), "--exchange", f"zenoh:{config}", "--fleet", fleet, "--steps", str(steps),
         "--period", str(period), "--report"], cwd=ROOT, stdout=subprocess.PIPE, text=True) for g in groups]
    for p in processes:
        if p.stdout.readline().strip() != "ready":
            raise RuntimeError("a publisher process did not start")
    stop = threading.Event()
    thread = threading.Thread(target=node.run, args=(stop,), daemon=True)
    cpu0, wall0 = time.process_time(), time.monotonic()
    thread.start()
    finished = 0
    for p in processes:
        finished += p.stdout.readline().strip() == "published"
    deadline = time.monotonic() + 30.0  # let the last updates reach a fusion
    while time.monotonic() < deadline and not all(seen.get(n) == steps - 1 for n in names):
        time.sleep(0.05)
    stop.set()
    thread.join()
    cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
    reports = []
    for p in processes:
        p.send_signal(signal.SIGTERM)
        reports.append(json.loads(p.stdout.readlines()[-1]))
        p.wait()
    exchange.close()
    robots = {k: v for r in reports for k, v in r["robots"].items()}
    seconds = np.median([r["seconds"] for r in reports])
    active = steps * period  # s during which a robot publishes
    sent = np.median([v["sent"].get("full", 0) + v["sent"].get("delta", 0) for v in robots.values()]) / active
    full_only = np.median([v["full_only"] for v in robots.values()]) / active
    status = np.median([v["sent"].get("status", 0) for v in robots.values()]) / active
    fusion_ms = np.median([1000 * h.seconds for h in node.history]) if node.history else float("nan")
    last = node.history[-1] if node.history else None
    return {"robots": size, "bytes_per_s_deltas": sent, "bytes_per_s_full": full_only, "bytes_per_s_status": status,
            "latency_median_ms": 1000 * np.median(latencies) if latencies else float("nan"),
            "latency_p90_ms": 1000 * np.percentile(latencies, 90) if latencies else float("nan"),
            "node_cpu_percent": 100 * cpu / wall, "fusions": len(node.history), "fusion_ms": fusion_ms,
            "cpu_ms_per_fusion": 1000 * cpu / max(1, len(node.history)),
            "all_aligned": bool(last and all(p.aligned for p in last.pairs)), "publish_seconds": seconds,
            "updates_fused": len(latencies), "updates_sent": size * steps}


def leave_latency(repeats: int = 5) -> list[float]:
    """Seconds from SIGKILL of a robot process to the fusion node seeing its liveliness token gone."""
    out = []
    for k in range(repeats):
        port, fleet = free_port(), f"leave{k}x{os.getpid()}"
        exchange = ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion")
        config = json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})
        p = subprocess.Popen([sys.executable, "-m", "runtime.fleet.synthetic", "--names", "robot1", "--exchange",
                              f"zenoh:{config}", "--fleet", fleet, "--steps", "1"], cwd=ROOT, stdout=subprocess.PIPE,
                             text=True)
        while "robot1" not in exchange.present():
            time.sleep(0.01)
        killed = time.monotonic()
        p.send_signal(signal.SIGKILL)
        while "robot1" in exchange.present():
            time.sleep(0.001)
        out.append(time.monotonic() - killed)
        p.wait()
        exchange.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=positive_int, nargs="+", default=[2, 4, 8, 16])
    parser.add_argument("--steps", type=positive_int, default=20, help="updates per robot (default 20)")
    parser.add_argument("--period", type=positive_float, default=0.5, help="s between a robot's updates (default 0.5)")
    parser.add_argument("--publishers", type=positive_int, default=4, help="publisher processes at most (default 4)")
    parser.add_argument("--leave", action="store_true", help="only measure how soon a killed robot is seen leaving")
    args = parser.parse_args()
    if args.leave:
        times = leave_latency()
        print(f"killed robot seen leaving after (s): median {np.median(times):.3f}, max {max(times):.3f} "
              f"over {len(times)} kills")
        return
    print(f"{args.steps} updates per robot every {args.period:g} s; maps grow 20 landmarks per update "
          f"(to {20 * args.steps}); the machine's load: {os.getloadavg()[0]:.1f}")
    header = (f"{'robots':>6} {'delta B/s':>10} {'full B/s':>10} {'ratio':>6} {'status B/s':>10} "
              f"{'lat med ms':>10} {'lat p90 ms':>10} {'node CPU %':>10} {'fusion ms':>9} {'CPU ms/fus':>10} "
              f"{'fused/sent':>10} aligned")
    print(header)
    for size in args.sizes:
        r = run_fleet(size, args.steps, args.period, args.publishers)
        print(f"{r['robots']:>6} {r['bytes_per_s_deltas']:>10.0f} {r['bytes_per_s_full']:>10.0f} "
              f"{r['bytes_per_s_full'] / r['bytes_per_s_deltas']:>6.1f} {r['bytes_per_s_status']:>10.0f} "
              f"{r['latency_median_ms']:>10.1f} {r['latency_p90_ms']:>10.1f} {r['node_cpu_percent']:>10.1f} "
              f"{r['fusion_ms']:>9.1f} {r['cpu_ms_per_fusion']:>10.1f} {r['updates_fused']:>4}/{r['updates_sent']:<5} "
              f"{r['all_aligned']}",
              flush=True)


if __name__ == "__main__":
    main()
