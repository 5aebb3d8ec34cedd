"""A chain run given ``--noise FILE`` (benchmarks.mrclam_constellation) and the tools that examine its saved states
again, on a synthetic MRCLAM log (tests/datasets/conftest.py's writer: exact sightings, so the model comes from a
file, as the in-sample fit of exact sightings cannot smooth): mrclam_honesty and mrclam_pass_support re-examine such a
state with the file's model (``saved_run_noise``), fitting none from the log.
"""
from __future__ import annotations

import inspect
import io
from contextlib import redirect_stdout

import pytest

import benchmarks.mrclam_constellation as mc
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise


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


@pytest.fixture
def run(data, tmp_path):
    """Seeds 0 and 1's runs given one noise file: (data, the noise file, the states)."""
    model = tmp_path / "model.toml"
    _model(0.02).save(model)
    for seed in (0, 1):
        assert _chain(data, model, tmp_path / "states", "--seed", str(seed)) == 0
    return data, model, tmp_path / "states"


@pytest.mark.parametrize("tool", ["honesty", "pass_support"])
def test_a_saved_state_is_re_examined_with_its_run_s_noise_file(run, tool, monkeypatch):
    """mrclam_honesty and mrclam_pass_support load a state given ``--noise FILE`` with the file's model (they fitted
    one in sample from the log before session 37)."""
    import importlib

    from estimation import noise_model

    module = importlib.import_module(f"benchmarks.mrclam_{tool}")
    data, model, states = run

    def no_fit(*args, **kwargs):
        raise AssertionError(f"mrclam_{tool} fitted a noise model from the log")

    for owner in (noise_model, mc, module):
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
