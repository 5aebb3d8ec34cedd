"""Every script of benchmarks/ answers ``--help`` with its usage, run as a user would type it
(``.venv/bin/python benchmarks/NAME.py --help``) from a folder that is not the repository: no traceback, no run
(three bench_* scripts ignored their arguments and ran the whole benchmark; seventeen others could not import
``benchmarks`` unless started with ``python -m`` from the repository root). A module of shared code without a
``__main__`` block (fusion_plots, slam_consistency) must at least import cleanly run that way.

Only the usage is checked here; each script's cheapest run is not (minutes for some, and the data set for many).

How each script is started: by a fork of one interpreter per test process (``_Forks``) that has imported only
third-party libraries (numpy, scipy, pydantic, mcap, rosbags, evo), and then runs the script as
``python benchmarks/NAME.py --help`` would: its own process, working folder, ``sys.argv``, ``sys.path`` (the
script's folder first, then exactly the fresh interpreter's path: no ``PYTHONPATH``, not the repository), stdin from
/dev/null, stdout and stderr to files, the script run as ``__main__`` and an uncaught exception printed and ending
the process as the interpreter does. Every module of this project (drivers, estimation, fusion, mocks, runtime,
benchmarks) is therefore imported in the script's own process, from its own ``sys.path``: the failures this test is
for (a project import that works only from the repository, a traceback at import, a script that runs instead of
answering) show exactly as in a fresh interpreter. The forking interpreter checks, before the first fork, that its
imports added no project module, changed neither ``sys.path`` nor the environment, and, before each fork, that it
has a single thread. What is no longer checked once per script is that those third-party libraries import in a
fresh interpreter: the forking interpreter, started as the scripts are, imports them once. The file alone, two runs
each at load 5-6: 51.5 and 49.4 s of CPU with a fresh interpreter per script, 34.8 and 33.3 s this way."""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = sorted((ROOT / "benchmarks").glob("*.py"))
PROJECT = ("drivers", "estimation", "fusion", "mocks", "runtime", "benchmarks")
# what the scripts import from outside the standard library and the project (measured with -X importtime)
THIRD_PARTY = ("numpy", "scipy.linalg", "scipy.sparse", "scipy.sparse.linalg", "scipy.spatial", "scipy.optimize",
               "scipy.special", "scipy.fft", "scipy.stats", "scipy.ndimage", "scipy.interpolate", "pydantic",
               "pydantic.main", "pydantic.fields", "pydantic.types", "pydantic.json_schema",
               "pydantic.functional_validators", "mcap.writer", "mcap.stream_reader", "rosbags.typesys",
               "rosbags.serde", "rosbags.rosbag1", "rosbags.rosbag2", "evo.core", "evo.core.trajectory",
               "evo.core.metrics", "evo.core.sync", "evo.tools", "evo.tools.file_interface")
# not OpenCV (its import sets LD_LIBRARY_PATH in os.environ) nor Rerun (its import starts threads)

# The forking interpreter: imports THIRD_PARTY, then for each request (a JSON line on stdin) forks; it answers the
# child's pid, then its exit code (negative for a signal, as subprocess does). The child leaves the loop and runs the
# script at the top level, so that the interpreter itself prints an uncaught exception, exits and runs atexit.
_FORKS = r"""
import importlib, importlib.util, json, os, sys
path, environ = list(sys.path), dict(os.environ)
for name in THIRD_PARTY:
    if importlib.util.find_spec(name.split(".")[0]) is not None:
        importlib.import_module(name)
own = sorted(m for m in sys.modules if m.split(".")[0] in PROJECT)
assert not own, f"the forking interpreter imported project modules: {own}"
assert sys.path == path and path[0] == "", f"the imports changed sys.path: {path} -> {sys.path}"
assert dict(os.environ) == environ, "the imports changed the environment"
while True:
    line = sys.stdin.readline()
    if not line:
        raise SystemExit(0)
    job = json.loads(line)
    threads = len(os.listdir("/proc/self/task"))
    if threads != 1:
        print(json.dumps({"error": f"{threads} threads in the forking interpreter"}), flush=True)
        continue
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        break
    print(json.dumps({"pid": pid}), flush=True)
    print(json.dumps({"returncode": os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])}), flush=True)
fd = os.open(os.devnull, os.O_RDONLY)
os.dup2(fd, 0)
os.close(fd)
for number, name in ((1, job["stdout"]), (2, job["stderr"])):
    fd = os.open(name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, number)
    os.close(fd)
os.chdir(job["cwd"])
sys.argv = [job["script"], *job["args"]]
sys.path[0] = os.path.dirname(job["script"])
del fd, number, name, line, path, environ, own, threads, pid
import runpy
runpy.run_path(sys.argv[0], run_name="__main__")
"""


class _Forks:
    """The forking interpreter of one test process, and the script runs it makes."""

    def __init__(self, folder: Path, env: dict[str, str]):
        self.folder = folder
        self.errors = folder / "forks.stderr"
        empty = folder / "empty"
        empty.mkdir()
        code = f"THIRD_PARTY = {THIRD_PARTY!r}\nPROJECT = {PROJECT!r}\n" + _FORKS
        with open(self.errors, "wb") as errors:
            self.process = subprocess.Popen([sys.executable, "-c", code], cwd=empty, env=env, stdin=subprocess.PIPE,
                                            stdout=subprocess.PIPE, stderr=errors, bufsize=0)
        self.pending = b""
        self.runs = 0

    def _answer(self, deadline: float) -> dict | None:
        """The next JSON line of the forking interpreter, or None at the deadline."""
        while b"\n" not in self.pending:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.process.stdout], [], [], left)[0]:
                return None
            chunk = os.read(self.process.stdout.fileno(), 65536)
            if not chunk:
                raise RuntimeError(f"the forking interpreter ended: {self.errors.read_text()}")
            self.pending += chunk
        line, self.pending = self.pending.split(b"\n", 1)
        answer = json.loads(line)
        if "error" in answer:
            raise RuntimeError(answer["error"])
        return answer

    def run(self, script: Path, *args: str, cwd: Path, timeout: float) -> subprocess.CompletedProcess:
        self.runs += 1
        out, err = self.folder / f"{self.runs}.stdout", self.folder / f"{self.runs}.stderr"
        job = {"script": str(script), "args": list(args), "cwd": str(cwd), "stdout": str(out), "stderr": str(err)}
        self.process.stdin.write((json.dumps(job) + "\n").encode())
        deadline = time.monotonic() + timeout
        started = self._answer(deadline)
        ended = self._answer(deadline) if started is not None else None
        if ended is None:
            if started is None:
                raise RuntimeError(f"the forking interpreter did not fork in {timeout} s: {self.errors.read_text()}")
            os.kill(started["pid"], signal.SIGKILL)
            self._answer(time.monotonic() + 60)
            raise subprocess.TimeoutExpired([sys.executable, str(script), *args], timeout)
        return subprocess.CompletedProcess([sys.executable, str(script), *args], ended["returncode"],
                                           out.read_text(), err.read_text())

    def close(self) -> None:
        self.process.stdin.close()
        try:
            self.process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.process.stdout.close()


@pytest.fixture(scope="module")
def _forks(tmp_path_factory):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"OPENBLAS_NUM_THREADS": "1"}
    forks = _Forks(tmp_path_factory.mktemp("forks"), env)
    yield forks
    forks.close()


def _is_script(path: Path) -> bool:
    return 'if __name__ == "__main__":' in path.read_text(encoding="utf-8")


def test_the_walk_finds_the_scripts():
    names = {p.name for p in SCRIPTS}
    assert len(SCRIPTS) >= 50 and {"fusion_sim.py", "eval_slam_rendered.py", "bench_fastslam.py"} <= names


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_help_prints_the_usage_without_a_traceback(script, tmp_path, _forks):
    # generous: the figures' speed is measured elsewhere; here a loaded machine must only not fail the test
    done = _forks.run(script, "--help", cwd=tmp_path, timeout=240)
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode == 0, done.stderr
    if _is_script(script):
        assert done.stdout.startswith("usage:"), done.stdout[:500]
    else:
        assert done.stdout == "", done.stdout[:500]
    assert list(tmp_path.iterdir()) == []   # --help writes nothing
