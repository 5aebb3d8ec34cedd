"""Benchmarks that read map folders (session 23): a missing, cut or absent map is one line naming the file, exit 2,
not a traceback; bench_fusion --demo-maps no longer measures a random pair instead of a folder it cannot read."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap

ROOT = Path(__file__).resolve().parents[2]
RUNS = [("bench_fusion.py", "--only-repeated", "--demo-maps"), ("fusion_prior.py", "--demo"),
        ("fusion_gate_scale.py", "--demo"), ("fusion_gate_scale.py", "--mrclam"), ("colocation_eval.py", "demo"),
        ("colocation_eval.py", "mrclam"), ("eval_fusion.py", "--maps-only", "--demo-maps")]


@pytest.fixture(scope="module")
def cut(tmp_path_factory) -> Path:
    """A folder with a sound robot1.npz and a robot2.npz cut short."""
    folder = tmp_path_factory.mktemp("maps")
    rng = np.random.default_rng(0)
    m = LandmarkMap(rng.normal(size=(20, 3)), np.tile(np.eye(3) * 0.01, (20, 1, 1)), rng.normal(size=(20, 8)),
                    robot="robot1")
    m.save(folder / "robot1.npz")
    m.robot = "robot2"
    m.save(folder / "robot2.npz")
    data = (folder / "robot2.npz").read_bytes()
    (folder / "robot2.npz").write_bytes(data[: len(data) // 2])
    return folder


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "benchmarks" / args[0]), *args[1:]], capture_output=True,
                          text=True, timeout=300, cwd=ROOT, env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))


@pytest.mark.parametrize("run", RUNS, ids=[" ".join(r) for r in RUNS])
def test_a_cut_map_in_the_folder_is_one_line(cut, run) -> None:
    p = _run([*run, str(cut)])
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert p.stderr.count("\n") == 1 and f"{cut}/robot2.npz" in p.stderr and "not a map file" in p.stderr


def test_bench_fusion_refuses_a_folder_without_maps(tmp_path) -> None:
    p = _run(["bench_fusion.py", "--only-repeated", "--demo-maps", str(tmp_path / "nothing")])
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "holds 0 robot*.npz" in p.stderr, p.stderr[-2000:]
    assert "repeated" not in p.stdout   # nothing measured on a random pair in its place
