"""Every script of benchmarks/ answers ``--help`` with its usage, run as a user would type it
(``.venv/bin/python benchmarks/NAME.py --help``) from a folder that is not the repository: no traceback, no run
(three bench_* scripts ignored their arguments and ran the whole benchmark; seventeen others could not import
``benchmarks`` unless started with ``python -m`` from the repository root). A module of shared code without a
``__main__`` block (fusion_plots, slam_consistency) must at least import cleanly run that way.

Only the usage is checked here; each script's cheapest run is not (minutes for some, and the data set for many)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted((ROOT / "benchmarks").glob("*.py"))


def _is_script(path: Path) -> bool:
    return 'if __name__ == "__main__":' in path.read_text(encoding="utf-8")


def test_the_walk_finds_the_scripts():
    names = {p.name for p in SCRIPTS}
    assert len(SCRIPTS) >= 50 and {"fusion_sim.py", "eval_slam_rendered.py", "bench_fastslam.py"} <= names


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_help_prints_the_usage_without_a_traceback(script, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"OPENBLAS_NUM_THREADS": "1"}
    # generous: the figures' speed is measured elsewhere; here a loaded machine must only not fail the test
    done = subprocess.run([sys.executable, str(script), "--help"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=240)
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 0, done.stderr
    if _is_script(script):
        assert done.stdout.startswith("usage:"), done.stdout[:500]
    else:
        assert done.stdout == "", done.stdout[:500]
    assert list(tmp_path.iterdir()) == []   # --help writes nothing
