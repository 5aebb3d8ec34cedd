"""How long a process takes to start: ``import fusion``, ``p3at fuse --help`` (or each ``--command``'s) and a
benchmark's ``--help``, in this tree and (``--baseline REV``) in an older revision's tree, runs alternated, medians
and ratios side by side.

Each measurement is a fresh ``python`` process (``OPENBLAS_NUM_THREADS=1``, the tree under test first on
``PYTHONPATH``), timed from spawn to exit (wall seconds): that is what a user and tests/benchmarks/test_scripts_help.py
pay. ``import fusion`` is also run under ``-X importtime`` and the package's own cumulative import time is read from
it, with whether ``scipy.stats`` was imported at all. The baseline tree is exported with ``git archive`` into
``--scratch`` (never into the repository); each row's baseline and current runs alternate, so a machine whose load
changes during the run shifts both alike.

    .venv/bin/python benchmarks/bench_import_time.py                                   # this tree only
    .venv/bin/python benchmarks/bench_import_time.py --baseline 397be2f --scratch /tmp/imports --repeats 9
    .venv/bin/python benchmarks/bench_import_time.py --baseline 397be2f --scratch /tmp/imports --all-scripts --repeats 2
    .venv/bin/python benchmarks/bench_import_time.py --baseline 47bef35 --scratch /tmp/imports --command demo \
        --command run
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.commands.options import positive_int  # noqa: E402


def help_code(words: list[str]) -> str:
    """Python code running ``p3at WORDS --help``."""
    return f"import sys; from runtime.cli import main; sys.argv = {['p3at', *words, '--help']!r}; sys.exit(main())"


def commands(tree: Path, script: str, helps: list[str]) -> dict[str, list[str]]:
    return {"import fusion": ["-c", "import fusion"],
            **{f"p3at {words} --help": ["-c", help_code(words.split())] for words in helps},
            f"{script} --help": [str(tree / "benchmarks" / script), "--help"]}


def environment(tree: Path) -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"PYTHONPATH": str(tree),
                                                                         "OPENBLAS_NUM_THREADS": "1"}


def wall(tree: Path, argv: list[str], cwd: Path) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, *argv], cwd=cwd, env=environment(tree), check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def importtime(tree: Path, cwd: Path) -> tuple[float, bool]:
    """(``fusion``'s cumulative import time in seconds, whether scipy.stats was imported) from ``-X importtime``."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", "import fusion"], cwd=cwd, env=environment(tree),
                          check=True, capture_output=True, text=True)
    rows = [line.split("|") for line in done.stderr.splitlines() if line.startswith("import time:")]
    cumulative = {name.strip(): int(total) for _self, total, name in rows if total.strip().isdigit()}
    return cumulative["fusion"] / 1e6, "scipy.stats" in cumulative


def check_tree(tree: Path, cwd: Path) -> None:
    """Refuse to measure a tree that is not the one imported (an installed copy would win over PYTHONPATH)."""
    done = subprocess.run([sys.executable, "-c", "import fusion; print(fusion.__file__)"], cwd=cwd,
                          env=environment(tree), check=True, capture_output=True, text=True)
    if not Path(done.stdout.strip()).resolve().is_relative_to(tree.resolve()):
        sys.exit(f"bench_import_time: {tree} is not what python imports ({done.stdout.strip()})")


def export(rev: str, scratch: Path) -> Path:
    tree = scratch / f"tree-{rev}"
    if not (tree / "fusion").is_dir():
        tree.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def all_scripts(trees: dict[str, Path], cwd: Path, repeats: int) -> None:
    """Each script's ``--help`` in both trees back to back (the order alternating), ``repeats`` times: per script the
    median of each tree, and the sums, which is what the help test's subprocesses cost."""
    (base_label, base), (_label, current) = trees.items()
    names = sorted(p.name for p in (current / "benchmarks").glob("*.py") if (base / "benchmarks" / p.name).exists())
    medians = {}
    for name in names:
        runs: dict[Path, list[float]] = {base: [], current: []}
        for k in range(repeats):
            for tree in ((base, current) if k % 2 == 0 else (current, base)):
                runs[tree].append(wall(tree, [str(tree / "benchmarks" / name), "--help"], cwd))
        medians[name] = (float(np.median(runs[base])), float(np.median(runs[current])))
    print(f"--help of {len(names)} benchmark scripts, {repeats} runs each per tree, back to back; medians in seconds")
    print(f"{'script':32} {base_label:>20} {'current':>10}  ratio")
    for name, (b, c) in medians.items():
        print(f"{name:32} {b:20.3f} {c:10.3f}  {c / b:.2f}")
    total_b, total_c = (sum(m[i] for m in medians.values()) for i in (0, 1))
    ratios = [c / b for b, c in medians.values()]
    print(f"{'sum':32} {total_b:20.2f} {total_c:10.2f}  {total_c / total_b:.2f}   (median of the ratios "
          f"{float(np.median(ratios)):.2f})")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", metavar="REV", help="a git revision to compare with (exported into --scratch)")
    parser.add_argument("--scratch", type=Path, help="folder for the baseline tree (default: a temporary folder)")
    parser.add_argument("--repeats", type=positive_int, default=7, help="runs of each command per tree (default 7)")
    parser.add_argument("--script", default="eval_fusion.py", help="the benchmark whose --help is timed "
                                                                   "(default eval_fusion.py)")
    parser.add_argument("--command", action="append", metavar="WORDS",
                        help="a p3at command whose --help is timed, e.g. 'demo' or 'slam dataset' (repeatable; "
                             "default fuse)")
    parser.add_argument("--all-scripts", action="store_true",
                        help="with --baseline: instead, every benchmark script both trees have, its --help run in "
                             "both trees back to back (what tests/benchmarks/test_scripts_help.py pays)")
    args = parser.parse_args(argv)
    if args.all_scripts and not args.baseline:
        parser.error("--all-scripts compares two trees: give --baseline REV")
    if args.scratch is not None and args.scratch.resolve().is_relative_to(ROOT):
        parser.error(f"--scratch {args.scratch} is inside the repository: give a folder outside it")
    with tempfile.TemporaryDirectory(prefix="bench_import_time-") as tmp:
        cwd = Path(tmp)
        trees = {"current": ROOT}
        if args.baseline:
            trees = {f"baseline {args.baseline}": export(args.baseline, args.scratch or cwd / "trees"), **trees}
        for tree in trees.values():
            check_tree(tree, cwd)
        if args.all_scripts:
            all_scripts(trees, cwd, args.repeats)
            return
        times: dict[tuple[str, str], list[float]] = {}
        stats_loaded: dict[str, bool] = {}
        for _ in range(args.repeats):
            for label, tree in trees.items():          # alternated: baseline, current, baseline, current ...
                for name, command in commands(tree, args.script, args.command or ["fuse"]).items():
                    times.setdefault((name, label), []).append(wall(tree, command, cwd))
                seconds, stats_loaded[label] = importtime(tree, cwd)
                times.setdefault(("import fusion (-X importtime, fusion's cumulative)", label), []).append(seconds)
    names = list(dict.fromkeys(name for name, _ in times))
    labels = list(trees)
    print(f"{args.repeats} runs per command and tree, alternated; medians in seconds "
          f"(OPENBLAS_NUM_THREADS=1, python {sys.version.split()[0]})")
    width = max(len(n) for n in names)
    print(f"{'':{width}}  " + "  ".join(f"{label:>22}" for label in labels) + ("   current/baseline" if
                                                                               len(labels) == 2 else ""))
    for name in names:
        medians = [float(np.median(times[name, label])) for label in labels]
        row = f"{name:{width}}  " + "  ".join(f"{m:22.3f}" for m in medians)
        if len(labels) == 2:
            row += f"   {medians[1] / medians[0]:.2f}"
        print(row)
    for label in labels:
        print(f"{label}: import fusion imports scipy.stats: {'yes' if stats_loaded[label] else 'no'}")


if __name__ == "__main__":
    main()
