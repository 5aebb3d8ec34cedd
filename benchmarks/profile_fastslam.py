"""FastSLAM update time on bench_pipeline's rendered workload, the filter alone (run by hand; prints figures).

The first run renders bench_pipeline's frames (robot1's route, 640×480, 15 Hz, the real front end, 150 corners)
and caches the observations and odometry poses in an npz; later runs replay only ``predict`` + ``update``, so
a change to the filter can be timed (CPU time, one thread) and profiled in seconds. ``--fingerprint`` prints a
digest of the final particles and maps: two versions of the filter that associate identically print the same.

    .venv/bin/python benchmarks/profile_fastslam.py [--frames 150] [--particles 100] [--cache PATH]
    .venv/bin/python benchmarks/profile_fastslam.py --profile 25      # cProfile, the 25 costliest functions
    .venv/bin/python benchmarks/profile_fastslam.py --synthetic       # bench_pipeline's synthetic observer
    .venv/bin/python benchmarks/profile_fastslam.py --against /tmp/old --repeat 30   # beside another checkout

``--against TREE``: the filter of another checkout (a git worktree of an older commit) is imported beside this one
and both replay the same frames in this process, run by run alternated, so the machine's load falls on both alike;
printed: each frame's minimum over the runs (mean over frames), the medians of the runs, new/old of each, and both
fingerprints (a change that keeps the results prints the same one twice).
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import cProfile  # noqa: E402
import hashlib  # noqa: E402
import pstats  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.config_overrides import config_overrides  # noqa: E402
from estimation.fastslam import FastSLAM, FastSLAMConfig  # noqa: E402
from estimation.geometry import between  # noqa: E402
from estimation.observations import OdometryIncrement, StereoObservations  # noqa: E402
from runtime.commands.options import non_negative_int, positive_float, positive_int  # noqa: E402


def record(path: Path, n_frames: int, rate: float, synthetic: bool) -> None:
    """Render (or synthesise) bench_pipeline's frames and save observations + odometry poses to ``path``."""
    from drivers.videre.head import StereoHead

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_pipeline import route_poses  # the same frames as the pipeline benchmark

    from estimation.frontend import FrontEnd, FrontEndConfig, HarrisConfig
    from mocks.stereo_head import VirtualStereoHead
    from mocks.synthetic_stereo import SyntheticStereo
    from mocks.world import World
    from runtime.adapters import VidereCamera

    world = World.load()
    world.add_robot("robot1", world.start_poses["robot1"])
    poses = route_poses(world, n_frames, rate)
    start = world.start_poses["robot1"]
    frames = []
    if synthetic:
        observer = SyntheticStereo.from_world(world, np.random.default_rng(1))
        for i, pose in enumerate(poses):
            frames.append(observer.observe(pose, i / rate)[0])
    else:
        virtual = VirtualStereoHead(world, "robot1", rng=np.random.default_rng(0))
        camera = VidereCamera(StereoHead.open(backend=virtual), rate=rate)
        front_end = FrontEnd(FrontEndConfig(geometry=camera.geometry, harris=HarrisConfig(max_corners=150)))
        for i, pose in enumerate(poses):
            world.set_pose("robot1", pose)
            frame = camera.read(timeout=2.0)
            frames.append(front_end.match(frame.left, frame.right).to_observations(i / rate))
        camera.close()
    counts = np.array([len(f) for f in frames])
    np.savez(path, counts=counts, odometry=np.array([between(start, p) for p in poses]),
             timestamps=np.array([f.timestamp for f in frames]),
             points=np.concatenate([f.points for f in frames]),
             covariances=np.concatenate([f.covariances for f in frames]),
             descriptors=np.concatenate([f.descriptors for f in frames]))


def load(path: Path) -> tuple[list[StereoObservations], np.ndarray]:
    data = np.load(path, allow_pickle=False)
    edges = np.r_[0, np.cumsum(data["counts"])]
    frames = [StereoObservations(data["points"][a:b], data["covariances"][a:b], data["descriptors"][a:b],
                                 np.zeros((0, 2)), float(t), "base_link")
              for a, b, t in zip(edges[:-1], edges[1:], data["timestamps"], strict=True)]
    return frames, data["odometry"]


def run(frames, odometry, config: FastSLAMConfig, seed: int = 0, filter_class=FastSLAM) -> tuple[FastSLAM, np.ndarray]:
    """SlamCore's sequence of predict/update calls; returns the filter and CPU ms per update (F,)."""
    slam = filter_class(config, np.random.default_rng(seed))
    update_ms = []
    for i, obs in enumerate(frames):
        if i:
            dx, dy, dth = between(odometry[i - 1], odometry[i])
            slam.predict(OdometryIncrement(float(dx), float(dy), float(dth), frames[i - 1].timestamp, obs.timestamp))
        t0 = time.process_time()
        slam.update(obs)
        update_ms.append(1e3 * (time.process_time() - t0))
    return slam, np.array(update_ms)


_LINKS: list[tempfile.TemporaryDirectory] = []   # kept for the process's life: a package may import lazily


def other_fastslam(tree: Path):
    """The ``estimation.fastslam`` package of another checkout, imported as ``estimation_against.fastslam`` (through a
    symlink in a temporary directory) beside this one: its modules import each other relatively, so none of this
    checkout's code mixes in."""
    import importlib

    source = (tree / "estimation").resolve()
    if not (source / "fastslam" / "filter.py").is_file():
        raise SystemExit(f"profile_fastslam: {tree} holds no estimation/fastslam/filter.py")
    links = tempfile.TemporaryDirectory(prefix="profile_fastslam_")
    _LINKS.append(links)
    (Path(links.name) / "estimation_against").symlink_to(source, target_is_directory=True)
    sys.path.insert(0, links.name)
    return importlib.import_module("estimation_against.fastslam")


def side_by_side(frames, odometry, fields: dict, tree: Path, runs: int) -> None:
    """This filter and ``tree``'s on the same frames, ``runs`` runs each, alternated; prints both and new/old."""
    other = other_fastslam(tree)
    filters = {"this": (FastSLAM, FastSLAMConfig), "against": (other.FastSLAM, other.FastSLAMConfig)}
    ms: dict[str, list[np.ndarray]] = {"this": [], "against": []}
    digests: dict[str, set[str]] = {"this": set(), "against": set()}
    for r in range(runs):
        for name in (("against", "this") if r % 2 == 0 else ("this", "against")):
            cls, config = filters[name]
            slam, times = run(frames, odometry, config(**fields), filter_class=cls)
            ms[name].append(times)
            digests[name].add(fingerprint(slam))
    new, old = np.array(ms["this"]), np.array(ms["against"])
    print(f"update CPU ms/frame, this checkout vs {tree}, {runs} runs each alternated (load "
          f"{os.getloadavg()[0]:.1f})")
    best_new, best_old = new.min(axis=0), old.min(axis=0)
    print(f"  each frame's minimum over the runs, mean over frames: {best_old.mean():.2f} -> {best_new.mean():.2f} "
          f"(new/old {best_new.mean() / best_old.mean():.3f}; last 50 frames "
          f"{best_new[-50:].mean() / best_old[-50:].mean():.3f})")
    for label, stat in (("median", np.median), ("mean", np.mean)):
        a, b = stat(old, axis=1), stat(new, axis=1)
        print(f"  {label} of a run: {statistics.median(a):.2f} -> {statistics.median(b):.2f} (new/old of the "
              f"alternated pairs: median {statistics.median(b / a):.3f}, {np.min(b / a):.3f}-{np.max(b / a):.3f})")
    print(f"  fingerprints: this {sorted(digests['this'])}, against {sorted(digests['against'])}")


def fingerprint(slam: FastSLAM) -> str:
    """Digest of every particle's pose, weight and map (ids, counts, rounded means)."""
    h = hashlib.sha256()
    h.update(np.round(slam.poses, 9).tobytes())
    h.update(np.round(slam.log_weights, 6).tobytes())
    for m in range(len(slam.poses)):
        lm = slam.particle_map(m, 1)
        h.update(lm.ids.tobytes())
        h.update(lm.counts.astype(np.int64).tobytes())
        h.update(np.round(lm.positions, 6).tobytes())
    return h.hexdigest()[:16]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=positive_int, default=150)
    parser.add_argument("--use", type=non_negative_int, default=0, metavar="N", help="replay only the first N frames")
    parser.add_argument("--rate", type=positive_float, default=15.0)
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--synthetic", action="store_true", help="bench_pipeline's synthetic observer instead")
    parser.add_argument("--cache", type=Path, default=None, help="observation cache (default in /tmp)")
    parser.add_argument("--repeat", type=positive_int, default=1, help="runs to time (the minimum total is printed)")
    parser.add_argument("--profile", type=non_negative_int, default=0, metavar="N",
                        help="cProfile; print the N costliest")
    parser.add_argument("--fingerprint", action="store_true", help="digest of the final particles and maps")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="FastSLAMConfig field")
    parser.add_argument("--against", type=Path, default=None, metavar="TREE",
                        help="another checkout: both filters on the same frames, --repeat runs each, alternated")
    args = parser.parse_args()
    kind = "synthetic" if args.synthetic else "rendered"
    cache = args.cache or Path(f"/tmp/profile_fastslam_{kind}_{args.frames}_{args.rate:g}.npz")
    if not cache.exists():
        record(cache, args.frames, args.rate, args.synthetic)
    frames, odometry = load(cache)
    if args.use:
        frames, odometry = frames[: args.use], odometry[: args.use]
    fields = {"n_particles": args.particles, "max_observations": 0, **config_overrides(args.set)}
    if args.against is not None:
        side_by_side(frames, odometry, fields, args.against, args.repeat)
        return
    config = FastSLAMConfig(**fields)
    if args.profile:
        profiler = cProfile.Profile()
        profiler.enable()
        slam, _ = run(frames, odometry, config)
        profiler.disable()
        pstats.Stats(profiler).sort_stats("cumulative").print_stats(args.profile)
        pstats.Stats(profiler).sort_stats("tottime").print_stats(args.profile)
        return
    best = None
    for _ in range(args.repeat):
        slam, ms = run(frames, odometry, config)
        best = ms if best is None or ms.sum() < best.sum() else best
    n_obs = np.mean([len(f) for f in frames])
    print(f"{kind}: {len(frames)} frames, {n_obs:.1f} observations/frame, {args.particles} particles, "
          f"{int(slam.particle_landmark_count()[slam.best_index])} landmarks (best particle)")
    print(f"update CPU ms/frame: mean {best.mean():.2f}  median {np.median(best):.2f}  p90 "
          f"{np.percentile(best, 90):.2f}  last 50 mean {best[-50:].mean():.2f}")
    if args.fingerprint:
        print(f"fingerprint {fingerprint(slam)}  best pose {np.round(slam.best_pose(), 4).tolist()}")


if __name__ == "__main__":
    main()
