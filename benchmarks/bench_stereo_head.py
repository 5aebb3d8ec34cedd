"""Stereo head figures: split + rectify throughput, render speed, end-to-end grab rate through pyusb.

Run by hand: ``.venv/bin/python benchmarks/bench_stereo_head.py`` (prints a Markdown table). OpenCV is held to
one thread, so every figure is for one core.
"""
from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from drivers.videre import StereoHead
from drivers.videre.frames import deinterleave, interleave
from mocks.stereo_head import VirtualStereoHead, default_calibration
from mocks.stereo_head.evaluation import window_alignment
from mocks.stereo_head.renderer import StereoRenderer
from mocks.world import World


def rate(fn, seconds: float = 1.5, warmup: int = 2) -> tuple[float, float]:
    """(per CPU second of this process, per wall second): the first is what one free core would do."""
    for _ in range(warmup):
        fn()
    count, start, cpu = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - start < seconds:
        fn()
        count += 1
    return count / (time.process_time() - cpu), count / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)  # no options: --help
    cv2.setNumThreads(1)  # the figures are for one core
    rng = np.random.default_rng(0)
    calib = default_calibration()
    rows = []
    for width, height in ((640, 480), (1280, 960)):
        scaled = calib.scaled(width, height)
        left, right = rng.integers(0, 256, (2, height, width), dtype=np.uint8)
        raw = interleave(left, right).reshape(-1).tobytes()
        _ = scaled.rectify_maps  # built once per size, like the driver's user does

        def split_rectify(raw=raw, width=width, height=height, scaled=scaled):
            l, r = deinterleave(raw, width, height)
            scaled.rectify(l, r)

        rows.append((f"split + rectify {width}x{height}", rate(split_rectify)))

    world = World.load()
    world.add_robot("bench", world.start_poses["robot1"])
    t0 = time.perf_counter()
    renderer = StereoRenderer(world, calib)
    bake = time.perf_counter() - t0
    pose = np.array(world.start_poses["robot1"], float)
    for width, height in ((640, 480), (1280, 960)):
        rows.append((f"render pair {width}x{height} (building, distortion)",
                     rate(lambda w=width, h=height: renderer.render(pose, (w, h)))))

    for width, height, fps in ((640, 480, 15.0), (1280, 960, 7.5)):
        virtual = VirtualStereoHead(world, "bench", rng=np.random.default_rng(1), renderer=renderer)
        with StereoHead.open(backend=virtual) as head:
            head.set_mode(width, height, fps)
            head.start()
            rows.append((f"grab through pyusb {width}x{height} (render + sensor + USB + split)",
                         rate(lambda head=head: head.grab())))

    vertical, horizontal = [], []
    for pose in ((3.0, 5.0, 0.0), (9.0, 4.8, 2.6), (21.0, 5.2, 3.0), (14.0, 4.6, 0.5)):
        world.set_pose("bench", np.array(pose))
        virtual = VirtualStereoHead(world, "bench", rng=np.random.default_rng(7), renderer=renderer)
        with StereoHead.open(backend=virtual) as head:
            calib = head.read_calibration()
            head.start()
            frame = head.grab()
        v, h = window_alignment(renderer, np.array(pose), *calib.rectify(frame.left, frame.right))
        vertical.append(np.abs(v))
        horizontal.append(np.abs(h))
    vertical, horizontal = np.concatenate(vertical), np.concatenate(horizontal)

    print("| operation | pairs per CPU second (one core) | pairs per wall second |")
    print("|---|---|---|")
    for name, (cpu, wall) in rows:
        print(f"| {name} | {cpu:.1f} | {wall:.1f} |")
    print(f"\ntexture atlas bake: {bake:.2f} s (once per building)")
    print(f"\nrectified rendered pairs, {len(vertical)} windows at 4 poses: epipolar error median "
          f"{np.median(vertical):.3f} px, 90th percentile {np.percentile(vertical, 90):.3f} px, max "
          f"{vertical.max():.3f} px; disparity error median {np.median(horizontal):.3f} px")


if __name__ == "__main__":
    main()
