"""A chain run given ``--noise FILE`` (benchmarks.mrclam_constellation) and the tools that examine its saved states
again, on a synthetic MRCLAM log (tests/datasets/conftest.py's writer: exact sightings, so the model comes from a
file, as the in-sample fit of exact sightings cannot smooth):

- every kept state records the file's content (SHA-256, hex) beside its path, in its meta and the final state's
  command, so the vote tells two files at one path apart (their commands differ);
- where a saved run's model is loaded again (``saved_run_noise``: the vote, mrclam_frame_nees, mrclam_honesty,
  mrclam_pass_support; ``--from-round``) a file whose content is no longer the recorded one is refused in one line;
  the same content again is accepted, and a state made before states recorded the digest keeps working;
- mrclam_honesty and mrclam_pass_support re-examine such a state with the file's model, fitting none from the log.
"""
from __future__ import annotations

import inspect
import io
import json
import shutil
from contextlib import redirect_stdout

import numpy as np
import pytest

import benchmarks.mrclam_constellation as mc
from estimation.noise_model import NoiseModel, NoiseModelError, OdometryNoise, RangeBearingNoise


def _model(range_sigma_m: float) -> NoiseModel:
    from .conftest import SENSOR_FOV, SENSOR_RANGE

    return NoiseModel(OdometryNoise(0.001, 0.002, 0.003),
                      RangeBearingNoise(range_sigma_m, 0.0, 0.01, fov_rad=SENSOR_FOV, max_range_m=SENSOR_RANGE))


COMMAND = ["--robots", "1", "--particles", "5", "--window", "20", "--max-rounds", "1"]


def _chain(data, noise_path, states, *extra) -> int:
    with redirect_stdout(io.StringIO()):
        return mc.main(["--data", str(data), *COMMAND, "--noise", str(noise_path), "--state-dir", str(states),
                        "--json", *extra])


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from .conftest import write_mrclam

    path = tmp_path_factory.mktemp("digest") / "data"
    write_mrclam(path, seconds=120.0)
    return path


@pytest.fixture(scope="module")
def _runs(data, tmp_path_factory):
    """Seeds 0 and 1's runs given one noise file, made once for the module: (the noise file, its bytes, the states'
    folder, a copy of the folder as the runs left it)."""
    folder = tmp_path_factory.mktemp("runs")
    model = folder / "model.toml"
    _model(0.02).save(model)
    for seed in (0, 1):
        assert _chain(data, model, folder / "states", "--seed", str(seed)) == 0
    shutil.copytree(folder / "states", folder / "as-made")
    return model, model.read_bytes(), folder / "states", folder / "as-made"


@pytest.fixture
def run(data, _runs):
    """Seeds 0 and 1's runs given one noise file: (data, the noise file, the states). The tests rewrite the file, the
    states' metas and add states; each starts from the files as the two runs left them, byte for byte (the runs are
    made once: 4 s each under load, six tests), at the paths the runs recorded (the states name the noise file by
    its path)."""
    model, content, states, as_made = _runs
    model.write_bytes(content)
    shutil.rmtree(states)
    shutil.copytree(as_made, states)
    return data, model, states


def _meta(path) -> dict:
    return mc.saved_meta(path)


def _rewrite_meta(path, change) -> None:
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))
    change(meta)
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)


def test_every_kept_state_records_the_file_s_content_beside_its_path(run):
    data, model, states = run
    digest = mc.file_sha256(model)
    assert len(digest) == 64 and int(digest, 16) >= 0
    kept = sorted(states.glob("*-seed0-*.npz"))
    assert {p.name for p in kept} >= {"Robot1-seed0-round0.npz", "Robot1-seed0-final.npz"}
    for path in kept:
        meta = _meta(path)
        assert (meta["noise"], meta["noise_sha256"]) == (str(model), digest), path.name
    command = _meta(states / "Robot1-seed0-final.npz")["command"]
    assert (command["noise"], command["noise_sha256"]) == (str(model), digest)
    for meta in (_meta(states / "Robot1-seed0-final.npz"), {"command": command}):
        assert (mc.saved_noise_file(meta), mc.saved_noise_sha256(meta)) == (str(model), digest)
    assert (mc.saved_noise_file({"robot": "in sample"}), mc.saved_noise_sha256({"robot": "in sample"})) == \
        (None, None)


def test_a_file_that_now_holds_another_model_is_refused_where_the_run_s_model_is_loaded_again(run, capsys):
    from benchmarks import mrclam_frame_nees, mrclam_honesty, mrclam_pass_support, mrclam_seed_vote
    from estimation.datasets import read_mrclam

    data, model, states = run
    original = model.read_bytes()
    _model(0.05).save(model)            # another model at the same path
    log = read_mrclam(data, 1)
    final = states / "Robot1-seed0-final.npz"
    with pytest.raises(NoiseModelError, match="other content") as e:
        mc.saved_run_noise(log, _meta(final))
    assert str(model) in str(e.value) and "\n" not in str(e.value)

    tools = {
        "vote": lambda: mrclam_seed_vote.main(["--data", str(data), "--state-dir", str(states), "--seeds", "0,1",
                                               "--robots", "1"]),
        "frame_nees": lambda: mrclam_frame_nees.main(["--data", str(data), str(final)]),
        "honesty": lambda: mrclam_honesty.main(["--data", str(data), "--state-dir", str(states), "--robots", "1",
                                                "--seeds", "0", "--tags", "round1"]),
        "pass_support": lambda: mrclam_pass_support.main(["--data", str(data), "--state-dir", str(states),
                                                          "--robots", "1", "--seeds", "0", "--rounds", "0"]),
    }
    for name, tool in tools.items():
        capsys.readouterr()
        with redirect_stdout(io.StringIO()):
            assert tool() == 2, name
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "other content" in err[0] and str(model) in err[0], (name, err)

    with pytest.raises(ValueError, match="other content"):      # resumed with the file as it is now
        _chain(data, model, states, "--from-round", "1", "--max-rounds", "2")

    model.write_bytes(original)         # the content the runs were given: accepted again
    assert mc.saved_run_noise(log, _meta(final)) == NoiseModel.load(model)
    assert _chain(data, model, states, "--from-round", "1", "--max-rounds", "2") == 0


def test_a_state_made_before_states_recorded_the_digest_keeps_working(run):
    from estimation.datasets import read_mrclam

    data, model, states = run

    def drop(meta):
        meta.pop("noise_sha256", None)
        meta.get("command", {}).pop("noise_sha256", None)

    for path in states.glob("*.npz"):
        _rewrite_meta(path, drop)
    final = states / "Robot1-seed0-final.npz"
    assert (mc.saved_noise_file(_meta(final)), mc.saved_noise_sha256(_meta(final))) == (str(model), None)
    assert mc.saved_run_noise(read_mrclam(data, 1), _meta(final)) == NoiseModel.load(model)
    assert _chain(data, model, states, "--from-round", "1", "--max-rounds", "2") == 0


def test_runs_given_two_files_at_one_path_are_not_voted_together(run):
    from benchmarks.mrclam_seed_vote import vote_robot
    from estimation.datasets import read_mrclam

    data, model, states = run
    _model(0.05).save(model)
    assert _chain(data, model, states, "--seed", "1") == 0        # seed 1 again, with the other content
    commands = [_meta(states / f"Robot1-seed{s}-final.npz")["command"] for s in (0, 1)]
    assert commands[0]["noise"] == commands[1]["noise"] and commands[0] != commands[1]
    with pytest.raises(SystemExit, match="different commands"):
        vote_robot(read_mrclam(data, 1), [str(states)], [0, 1])


@pytest.mark.parametrize("tool", ["honesty", "pass_support"])
def test_a_saved_state_is_re_examined_with_its_run_s_noise_file(run, tool, monkeypatch):
    """mrclam_honesty and mrclam_pass_support load a state given ``--noise FILE`` with the file's model (they fitted
    one in sample from the log before session 37)."""
    import importlib

    from estimation import noise_estimation

    module = importlib.import_module(f"benchmarks.mrclam_{tool}")
    data, model, states = run

    def no_fit(*args, **kwargs):
        raise AssertionError(f"mrclam_{tool} fitted a noise model from the log")

    for owner in (noise_estimation, mc, module):
        if hasattr(owner, "estimate_noise"):
            monkeypatch.setattr(owner, "estimate_noise", no_fit)
    given = []
    f = module.load_saved_state

    def spy(*args, **kwargs):
        given.append(inspect.signature(f).bind(*args, **kwargs).arguments["noise"])
        return f(*args, **kwargs)

    monkeypatch.setattr(module, "load_saved_state", spy)
    which = ["--tags", "round0,round1"] if tool == "honesty" else ["--rounds", "0,1"]
    with redirect_stdout(io.StringIO()):
        assert module.main(["--data", str(data), "--state-dir", str(states), "--robots", "1", "--seeds", "0",
                            *which]) == 0
    assert len(given) == 2 and all(noise == NoiseModel.load(model) for noise in given)
