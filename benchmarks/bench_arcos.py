"""ARCOS driver figures: codec throughput, and the CPU the driver uses while following a robot at 10 SIPs/s.

    .venv/bin/python benchmarks/bench_arcos.py [--seconds 20] [--transport tcp|pty]

1. Packets per second through the streaming parser alone, parser + SIP decoding, and parser + decoding + state
   tracking (the reader thread's whole per-SIP work), on a stream of full SIPs (16 sonar readings, every optional
   field) fed in 4 KiB chunks.
2. The driver connected to a virtual P3-AT run in a separate process (``p3at robot serve``), so this process
   holds only the driver: process CPU time over wall time while it follows the robot's 10 SIPs/s (PULSE
   keep-alives included). Goal: under 1 % of one core.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.arcos.codec import PacketParser, Sip, decode_sip, encode_packet, encode_sip  # noqa: E402
from drivers.arcos.params import builtin_params  # noqa: E402
from drivers.arcos.robot import P3AT  # noqa: E402
from drivers.arcos.state import StateTracker  # noqa: E402
from runtime.commands.options import positive_float  # noqa: E402


def full_sip(i: int) -> bytes:
    return encode_packet(encode_sip(Sip(
        moving=True, xpos=(i * 37) & 0x7FFF, ypos=(i * 11) & 0x7FFF, thpos=i % 4096, lvel=300, rvel=310,
        battery=128, flags=0x1F, sonars=tuple((k, 1000 + 10 * k) for k in range(16)), battery_x10=128,
        charge_state=0, rotvel=5, fault_flags=0, latvel=0, temperature=30, soc=90, uc_time=i, flags3=0)))


def bench_codec(n_packets: int = 20000) -> None:
    stream = b"".join(full_sip(i) for i in range(n_packets))
    chunks = [stream[i:i + 4096] for i in range(0, len(stream), 4096)]
    params = builtin_params("p3at-sh")
    print(f"codec: {n_packets} full SIPs of {len(full_sip(0))} bytes, fed in 4 KiB chunks")
    for label, decode, track in (("parse only", False, False), ("parse + decode_sip", True, False),
                                 ("parse + decode + state", True, True)):
        parser, tracker = PacketParser(), StateTracker(params)
        start = time.perf_counter()
        count = 0
        for chunk in chunks:
            for payload in parser.feed(chunk):
                count += 1
                if decode:
                    sip = decode_sip(payload)
                    if track:
                        tracker.update(sip, 0.0)
        elapsed = time.perf_counter() - start
        assert count == n_packets, (count, parser.stats)
        print(f"  {label:24s} {count / elapsed:>10,.0f} packets/s  ({elapsed / count * 1e6:6.1f} us/packet)")


def bench_driver_cpu(seconds: float, transport: str) -> None:
    where = ["--tcp", "0"] if transport == "tcp" else ["--pty"]
    server = subprocess.Popen(
        [sys.executable, "-m", "runtime.cli", "robot", "serve", *where, "--duration", str(seconds + 10)],
        cwd=ROOT, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        url = None
        for line in server.stdout:
            match = re.search(r"listening on (\S+)", line)
            if match:
                url = match.group(1)
                break
        if url is None:
            raise SystemExit("the virtual robot did not start")
        states = []
        with P3AT(url) as robot:
            robot.subscribe(states.append)
            robot.wait_for_state()
            time.sleep(1.0)  # settle: imports and the first packets are not the steady state
            states.clear()
            cpu0, wall0 = time.process_time(), time.perf_counter()
            time.sleep(seconds)
            cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
            n = len(states)
        print(f"driver following a virtual P3-AT over {transport} ({url}) for {wall:.1f} s:")
        print(f"  {n / wall:.1f} SIPs/s received, process CPU {cpu * 1000:.0f} ms = {100 * cpu / wall:.2f} % of one "
              f"core ({cpu / max(n, 1) * 1e6:.0f} us per SIP, keep-alive and wake-ups included)")
    finally:
        server.terminate()
        server.wait(10)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=positive_float, default=20.0,
                        help="how long to follow the robot (default 20)")
    parser.add_argument("--transport", choices=("tcp", "pty", "both"), default="both")
    args = parser.parse_args()
    bench_codec()
    for transport in (("tcp", "pty") if args.transport == "both" else (args.transport,)):
        bench_driver_cpu(args.seconds, transport)


if __name__ == "__main__":
    main()
