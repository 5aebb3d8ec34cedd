"""Speed of the simulated building and the virtual P3-AT (run by hand; prints figures, asserts nothing).

    .venv/bin/python benchmarks/bench_world.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.arcos.codec import encode_command, encode_packet
from drivers.arcos.commands import Command
from mocks.p3at import VirtualP3AT
from mocks.world import World


def rate(fn, repeat: int) -> float:
    """Calls per second of fn() (best of three runs of ``repeat`` calls)."""
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        for _ in range(repeat):
            fn()
        best = min(best, time.perf_counter() - start)
    return repeat / best


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)  # no options: --help
    world = World.load()
    rng = np.random.default_rng(0)
    print(f"world {world.name!r}: {len(world.walls)} wall pieces, {len(world.features)} features")
    for n in (16, 640, 10_000):
        origins = np.column_stack([rng.uniform(1, 34, n), rng.uniform(4, 6, n)])
        angles = rng.uniform(-np.pi, np.pi, n)
        calls = rate(lambda o=origins, a=angles: world.raycast(o, a, 5.0), max(3, 20_000 // n))
        print(f"raycast batch of {n:>6}: {calls * n:>12,.0f} rays/s ({calls:,.0f} calls/s)")
    print(f"collides:                {rate(lambda: world.collides(10.0, 5.0, 0.33), 2000):>12,.0f} calls/s")
    eye = np.array([5.0, 5.0, 0.0])
    fov = np.radians(60)
    print(f"visible_features:        {rate(lambda: world.visible_features(eye, 0.5, fov, 10.0), 300):>12,.0f} calls/s")

    model = VirtualP3AT(world, "bench", world.start_poses["robot1"])
    for sync in (0, 1, 2):
        model.receive(encode_packet(bytes([sync])), 0.0)
    model.receive(encode_command(Command.OPEN) + encode_command(Command.ENABLE, 1), 0.0)
    model.receive(encode_command(Command.VEL, 300) + encode_command(Command.RVEL, 5), 0.0)
    t = [0.0]

    def second() -> None:
        t[0] += 1.0
        model.receive(encode_command(Command.PULSE), t[0])

    seconds = rate(second, 20)
    print(f"model: {seconds * 100:,.0f} physics steps/s (10 ms each) = {seconds:,.0f}× real time, "
          f"with 10 SIPs and 25 sonar readings per simulated second")
    model.close()


if __name__ == "__main__":
    main()
