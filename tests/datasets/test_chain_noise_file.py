"""The unknown-association chain (benchmarks/mrclam_constellation, issue 13) with its noise model from a file
(``--noise FILE``, a model `p3at slam noise` writes): a lab calibrates once on a run with ground truth and maps other
runs, so the chain must take the model as given and fit nothing from the log it maps.

On MRCLAM robot 1's first 300 s (session 30's command, 10 particles, as tests/datasets/test_chain_blind.py):
- a file holding the very model ``run_robot`` fits in sample gives the same run: every kept state equal, bit for bit;
- a file holding another model (robot 2's) is the one every step of the chain is given — the chained names, the
  filter's guess, every smoothing, the merges' smoother, the leave-outs, the naming — and nothing is fitted from the
  log; with ``--names-cache`` the chain's cached names and guesses go to a folder of that model's own;
- the final state records the file and its content's SHA-256 in its command (an in-sample run's command has neither, as
  before the option), so ``benchmarks.mrclam_seed_vote`` refuses to vote runs of different noise models (or two
  files at one path) together.
"""
from __future__ import annotations

import hashlib
import inspect
import io
import json
import re
import shutil
from contextlib import redirect_stdout

import numpy as np
import pytest

from .test_chain_blind import COMMAND, STATE_ARRAYS


def _log(robot: int, until: float = 300.0):
    from estimation.datasets import read_mrclam

    from .conftest import MRCLAM2

    if not MRCLAM2.is_dir():
        pytest.skip("MRCLAM data set 2 is not in ../shared/data")
    return read_mrclam(MRCLAM2, robot, until=until)


def _run(mc, log, options, directory, monkeypatch) -> dict:
    from .conftest import MRCLAM2

    monkeypatch.setattr(mc, "read_mrclam", lambda data, robot: log)
    with redirect_stdout(io.StringIO()) as out:
        assert mc.main(["--data", str(MRCLAM2), *COMMAND, *options, "--state-dir", str(directory)]) == 0
    return json.loads(out.getvalue())


def _states(directory) -> dict:
    states = {}
    for path in sorted(directory.glob("*.npz")):
        with np.load(path, allow_pickle=False) as data:
            states[path.name] = {key: data[key] for key in STATE_ARRAYS}
    return states


def _command(directory) -> dict:
    with np.load(directory / "Robot1-seed0-final.npz", allow_pickle=False) as data:
        return json.loads(str(data["meta"]))["command"]


@pytest.mark.timeout(1200)  # CPU-bound; the vote took 135 s at load 3 and passed 300 s beside a loaded CI
@pytest.mark.slow  # the chain twice on 300 s of one robot (~15 s CPU each)
def test_a_file_holding_the_in_sample_model_gives_the_same_run_and_the_vote_refuses_to_mix_them(tmp_path, monkeypatch):
    import benchmarks.mrclam_constellation as mc
    import benchmarks.mrclam_seed_vote as vote
    from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise
    from estimation.noise_model import NoiseModel

    from .conftest import MRCLAM2

    log = _log(1)
    path = tmp_path / "robot1.toml"
    estimate_noise([log], **DATASET_CALIBRATIONS).model.save(path)
    assert NoiseModel.load(path) == estimate_noise([log], **DATASET_CALIBRATIONS).model     # the file holds it all
    in_sample = _run(mc, log, [], tmp_path / "in-sample", monkeypatch)
    from_file = _run(mc, log, ["--noise", str(path)], tmp_path / "file", monkeypatch)
    assert in_sample["noise"] is None and from_file["noise"] == str(path)
    a, b = _states(tmp_path / "in-sample"), _states(tmp_path / "file")
    assert len(a) >= 5 and a.keys() == b.keys()        # the chain, rounds, pairwise rounds, leave-outs, final
    for name in a:
        for key in STATE_ARRAYS:
            assert np.array_equal(a[name][key], b[name][key]), (name, key)
    assert json.dumps(from_file["robots"][0]["final"]) == json.dumps(in_sample["robots"][0]["final"])

    assert "noise" not in _command(tmp_path / "in-sample")     # as before the option existed: old states still vote
    assert _command(tmp_path / "file") == {**_command(tmp_path / "in-sample"), "noise": str(path),
                                           "noise_sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    # the file's run as seed 1 beside the in-sample run of seed 0: the same names, but not the same command
    for tag in ("final", "round0"):
        shutil.copy(tmp_path / "file" / f"Robot1-seed0-{tag}.npz", tmp_path / "in-sample" / f"Robot1-seed1-{tag}.npz")
    monkeypatch.setattr(vote, "read_mrclam", lambda data, robot: log)
    with pytest.raises(SystemExit, match="different commands"), redirect_stdout(io.StringIO()):
        vote.main(["--data", str(MRCLAM2), "--state-dir", str(tmp_path / "in-sample"), "--seeds", "0,1",
                   "--robots", "1"])


@pytest.mark.timeout(1200)  # CPU-bound; the vote took 135 s at load 3 and passed 300 s beside a loaded CI
@pytest.mark.slow  # the chain once on 300 s of one robot (~15 s CPU)
def test_the_chain_fits_nothing_from_the_log_and_every_step_is_given_the_file_s_model(tmp_path, monkeypatch):
    import benchmarks.mrclam_constellation as mc
    from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise
    from estimation.noise_model import NoiseModel

    log = _log(1)
    path = tmp_path / "robot2.toml"
    estimate_noise([_log(2)], **DATASET_CALIBRATIONS).model.save(path)
    model = NoiseModel.load(path)
    assert model != estimate_noise([log], **DATASET_CALIBRATIONS).model

    def no_fit(*args, **kwargs):
        raise AssertionError("the chain fitted a noise model from the log it maps")

    monkeypatch.setattr(mc, "estimate_noise", no_fit)
    given: dict[str, list] = {}

    def spy(name, f):
        signature = inspect.signature(f)

        def wrapped(*args, **kwargs):
            given.setdefault(name, []).append(signature.bind(*args, **kwargs).arguments["noise"])
            return f(*args, **kwargs)
        return wrapped

    # every callable the chain's module holds, or reaches through the estimation modules it holds, that takes a
    # noise model: each call's model is recorded
    from estimation import chain_run, name_chain, name_leave_out, name_merging, pairwise_rounds, unnamed_sightings

    for owner in (mc, name_chain, chain_run, pairwise_rounds, name_leave_out, name_merging, unnamed_sightings):
        for name, f in list(vars(owner).items()):
            if not callable(f) or name.startswith("__") or getattr(f, "__module__", None) == mc.__name__:
                continue
            try:
                parameters = inspect.signature(f).parameters
            except (TypeError, ValueError):
                continue
            if "noise" in parameters:
                monkeypatch.setattr(owner, name, spy(f"{owner.__name__}.{name}", f))
    row = _run(mc, log, ["--noise", str(path), "--names-cache", str(tmp_path / "cache")], tmp_path / "states",
               monkeypatch)["robots"][0]

    called = {name.rsplit(".", 1)[1] for name in given}
    assert {"_chained", "names_guess", "smooth_named", "NamedSmoother", "unconfirmed_names"} <= called, called
    for name, models in given.items():
        assert all(m == model for m in models), name
    assert row["final"]["names"] > 0
    assert _command(tmp_path / "states")["noise"] == str(path)
    # the chained names and the guess depend on the model: cached in a folder of its own
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    cached = sorted(p.relative_to(tmp_path / "cache") for p in (tmp_path / "cache").rglob("*") if p.is_file())
    assert cached and all(p.parts[0] == f"noise-{digest}" for p in cached), cached


def test_a_noise_file_without_a_sensor_or_unreadable_is_refused_in_one_line(tmp_path, capsys):
    import benchmarks.mrclam_constellation as mc
    from estimation.noise_model import NoiseModel, OdometryNoise

    odometry_only = tmp_path / "odometry.toml"
    NoiseModel(OdometryNoise(0.01, 0.01, 0.0)).save(odometry_only)
    data = tmp_path / "data"
    data.mkdir()        # checked before the model: an empty folder will do, no robot is read
    for path, why in ((odometry_only, "no [range_bearing] section"), (tmp_path / "absent.toml", "no such")):
        assert mc.main(["--data", str(data), "--noise", str(path)]) == 2
        err = capsys.readouterr().err
        assert why in err and err.count("\n") == 1, err


def test_a_run_resumed_from_a_state_made_with_another_noise_model_is_refused(tmp_path, monkeypatch):
    """``--from-round K`` goes on from a kept state: the state's noise model (its meta's ``noise`` file; absent: fitted
    in sample) must be the run's, as its drift, path step and heading loss must."""
    import benchmarks.mrclam_constellation as mc
    from estimation.landmark_smoother import HeadingDrift
    from estimation.named_smoothing import MergeRound, smooth_named
    from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise

    from .conftest import MRCLAM2

    log = _log(2, until=60.0)
    noise = estimate_noise([log], **DATASET_CALIBRATIONS).model
    path = tmp_path / "model.toml"
    noise.save(path)
    monkeypatch.setattr(mc, "read_mrclam", lambda data, robot: log)
    drift = HeadingDrift(0.16, 10.0)                  # the benchmark's defaults (no slip)
    names = np.asarray(log.landmark_ids, np.int64)
    named, solution = smooth_named(log, names, noise, mc.range_bearing_config(n_particles=10), heading_drift=drift,
                                   path_step_s=0.25)
    command = ["--data", str(MRCLAM2), "--robots", "2", "--particles", "10", "--from-round", "1"]
    for made_with, resumed_with in ((None, ["--noise", str(path)]), (str(path), [])):
        directory = tmp_path / str(made_with is None)
        meta = {"robot": log.name, "seed": 0, "drift": mc._drift_meta(drift), "path_step_s": 0.25, "round": 1,
                "scores": {}, "sighting_offset_m": 0.0, **({"noise": made_with} if made_with else {})}
        mc.save_state(mc.state_path(directory, log, 0, "round1"), MergeRound([], 0.0, 0.0, True, names, named,
                                                                             solution), meta)
        with pytest.raises(ValueError, match=re.escape(f"made with noise {made_with!r}, not "
                                                       f"{(str(path) if resumed_with else None)!r}")):
            mc.main([*command, "--state-dir", str(directory), *resumed_with])
