"""Wrong arguments on what came since session 14 (session 23): start poses and their σ of any finite size, a
particle count that would take the machine's memory, `fuse --live --seconds 1e300`. Each is a one-line error
(exit 2) or works; none is a warning storm, an internal error, a thread's traceback or the kernel's OOM kill."""
from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fusion.errors import IncompatibleMapsError
from fusion.prior import load_starts, named_pair_priors, parse_start
from runtime.fleet.processes import free_port
from tests.datasets.conftest import run_cli
from tests.hardening.test_map_metadata import _pair

ROOT = Path(__file__).resolve().parents[2]
finite = st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                   st.sampled_from([1e300, -1e300, 1e155, 1e-300, 0.0, 1e6, 1e7]))


@settings(max_examples=300)
@given(pose=st.tuples(finite, finite, finite), sigmas=st.tuples(finite, finite))
@example(pose=(1e300, 0.0, 0.0), sigmas=(1.0, 0.3))     # RuntimeWarnings (overflow in the prior's covariance)
@example(pose=(0.0, 0.0, 0.0), sigmas=(1e300, 1e300))   # OverflowError: exit 70
@example(pose=(0.0, 0.0, 1e300), sigmas=(1.0, 0.3))
def test_any_finite_start_is_a_prior_or_one_line(pose, sigmas) -> None:
    text = ",".join(repr(v) for v in (*pose, *sigmas))
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # an overflow's RuntimeWarning fails the test
        try:
            start = parse_start(text)
            priors = named_pair_priors({"robot1": start, "robot2": (np.zeros(3), (1.0, 0.3))})
        except IncompatibleMapsError as e:
            assert "\n" not in str(e)
            return
    prior = priors[("robot1", "robot2")]
    assert np.all(np.isfinite(prior.mean)) and np.all(np.isfinite(prior.covariance))


def test_a_start_pose_file_with_a_huge_default_sigma_names_the_file(tmp_path) -> None:
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"sigma_xy": 1e300, "sigma_yaw": 1, "starts": {"robot1": [0, 0, 0]}}))
    with pytest.raises(IncompatibleMapsError, match=rf"^{path}: sigma_xy, sigma_yaw: .* at most 1e\+06"):
        load_starts(str(path))


@pytest.mark.parametrize("option", ["--start-sigma=1e300,1e300", "--start-pose=robot1=0,0,0,1e300,1"])
def test_fuse_with_a_huge_start_sigma_is_one_line(tmp_path, option) -> None:
    maps = []
    for m in _pair():
        m.save(tmp_path / f"{m.robot}.npz")
        maps.append(str(tmp_path / f"{m.robot}.npz"))
    others = ["--start-pose=robot1=0,0,0"] if option.startswith("--start-sigma") else ["--start-pose=robot2=0,0,0,1,1"]
    status, _, err = run_cli("fuse", *maps, "--out", str(tmp_path / "out.npz"), option, *others,
                             "--start-pose=robot2=1,-2,0.4" if option.startswith("--start-sigma") else "--json")
    assert status == 2 and err.count("\n") == 1 and "1e" in err, err   # was exit 70 (OverflowError)


@pytest.mark.parametrize("argv", [
    ["slam", "dataset", "mrclam", "/nonexistent", "--robot", "1", "--out", "x.npz", "--particles", "100000000"],
    ["slam", "simulate", "--particles", "10001"],
    ["demo", "--particles", "1000000000"],
    ["run", "--particles", "99999"],
    ["replay", "/nonexistent", "--particles", "20000"],
])
def test_a_particle_count_beyond_the_bound_is_refused_before_any_work(argv) -> None:
    """`slam dataset --particles 100000000` was killed by the kernel at 22 GB of RSS after 94 s."""
    status, _, err = run_cli(*argv)
    assert status == 2 and err.count("\n") == 1, err
    assert "--particles: expected a whole number >= 1 and at most 10000 (particles)" in err, err


def test_the_bound_admits_its_own_maximum(tmp_path) -> None:
    from runtime.commands.options import particle_count
    from runtime.limits import MAX_PARTICLES

    assert particle_count(str(MAX_PARTICLES)) == MAX_PARTICLES and particle_count("1") == 1


def test_fuse_live_for_1e300_seconds_runs_until_interrupted(tmp_path) -> None:
    """The --seconds timer's thread died with 'OverflowError: timestamp out of range' (a traceback on stderr) and
    the node ran on; now such a number means until Ctrl-C, which ends it as usual."""
    port = free_port()
    config = tmp_path / "node.json5"
    config.write_text(json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}))
    node = subprocess.Popen([sys.executable, "-m", "runtime.cli", "fuse", "--live", "--exchange", f"zenoh:{config}",
                             "--seconds", "1e300", "--fleet", f"b{port}"], cwd=ROOT, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:         # the node listens: its exchange is open, its timer next
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert node.poll() is None, node.stderr.read()
                time.sleep(0.1)
        else:
            pytest.fail("the node did not listen within 60 s")
        time.sleep(1.0)     # not a wait for a condition: the old timer's traceback came at once; this only lets it
        node.send_signal(signal.SIGINT)
        _, err = node.communicate(timeout=60)
    finally:
        if node.poll() is None:
            node.kill()
    assert "Traceback" not in err and "OverflowError" not in err, err
    assert "nothing to fuse" in err
