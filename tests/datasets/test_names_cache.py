"""``--names-cache`` (benchmarks.mrclam_chained_names._chained, benchmarks.mrclam_constellation._guess): an entry is
read back only for what it was made from.

Its file is named by robot, window, step, seed and particles only; inside it holds the digest of the log as read
(a log read to another time is another log), the noise model's content, the filter's configuration and the settings
(``cache_digest``). On a synthetic MRCLAM log (tests/datasets/conftest.py's writer, exact sightings):
- an entry made from the log's first 60 s is not used for its first 90 s, nor with another noise model: computed
  again (said once on stderr) and replaced, the result the same as without a cache;
- an entry made from the same log, model and settings is used: the windows' filter (``chain_log``) and the guess's
  filter (``names_guess``) are not run;
- an entry written before entries carried a digest is computed again, never trusted.
"""
from __future__ import annotations

import argparse
import shutil

import numpy as np
import pytest

import benchmarks.mrclam_chained_names as cn
import benchmarks.mrclam_constellation as mc
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    from .conftest import write_mrclam

    path = tmp_path_factory.mktemp("synthetic")
    write_mrclam(path, seconds=120.0)
    return path


def _noise(range_sigma_m: float = 0.02) -> NoiseModel:
    from .conftest import SENSOR_FOV, SENSOR_RANGE

    return NoiseModel(OdometryNoise(0.001, 0.002, 0.003),
                      RangeBearingNoise(range_sigma_m, 0.0, 0.01, fov_rad=SENSOR_FOV, max_range_m=SENSOR_RANGE))


CONFIG = range_bearing_config(n_particles=5)


def _args(cache) -> argparse.Namespace:
    return argparse.Namespace(window=20.0, step=None, seed=0, particles=5, names_cache=str(cache))


@pytest.fixture
def calls(monkeypatch):
    """How often the windows' filter and the guess's filter ran."""
    counts = {"chain_log": 0, "names_guess": 0}

    def counting(name, f):
        def wrapper(*a, **k):
            counts[name] += 1
            return f(*a, **k)
        return wrapper

    monkeypatch.setattr(cn, "chain_log", counting("chain_log", cn.chain_log))
    monkeypatch.setattr(mc, "names_guess", counting("names_guess", mc.names_guess))
    return counts


def _both(log, noise, args):
    chained, row = cn._chained(log, args, noise, CONFIG)
    poses, guess = mc._guess(log, chained.names, noise, CONFIG, args)
    return chained.names, row, poses, guess


@pytest.fixture(scope="module")
def _filled(folder, tmp_path_factory):
    """The cache filled from the log's first 60 s with the default model and settings, by both entries' first
    computation (made once per module: four tests start from it, each on its own copy, :func:`_filled_cache`):
    (the cache folder, the chained names, their row, the guess's poses and guess)."""
    cache = tmp_path_factory.mktemp("filled") / "cache"
    log = read_mrclam(folder, 1, until=60.0)
    chained, row = cn._chained(log, _args(cache), _noise(), CONFIG)
    poses, guess = mc._guess(log, chained.names, _noise(), CONFIG, _args(cache))
    for array in (chained.names, poses, *guess.values()):
        array.flags.writeable = False           # shared by the tests: read only
    return cache, chained, row, poses, guess


def _filled_cache(filled, tmp_path):
    """A copy, in ``tmp_path``, of the cache :func:`_filled` made; its args."""
    shutil.copytree(filled[0], tmp_path / "cache")
    return _args(tmp_path / "cache")


def _same(a, b) -> None:
    names, row, poses, guess = a
    names_b, row_b, poses_b, guess_b = b
    np.testing.assert_array_equal(names, names_b)
    assert {k: v for k, v in row.items() if k != "window_cpu_s"} == \
        {k: v for k, v in row_b.items() if k != "window_cpu_s"}
    np.testing.assert_array_equal(poses, poses_b)
    assert sorted(guess) == sorted(guess_b)
    for k in guess:
        np.testing.assert_array_equal(guess[k], guess_b[k])


def test_an_entry_of_a_shorter_log_is_computed_again_and_a_matching_one_is_used(folder, _filled, tmp_path, calls,
                                                                                  capsys):
    short, long = read_mrclam(folder, 1, until=60.0), read_mrclam(folder, 1, until=90.0)
    assert short.name == long.name and len(short.sighting_times) < len(long.sighting_times)
    noise = _noise()
    expected = _both(long, noise, _args(tmp_path / "elsewhere"))     # the long log's, from no cache
    args = _filled_cache(_filled, tmp_path)       # the cache as filled from the first 60 s
    assert sorted(p.name for p in (tmp_path / "cache").rglob("*.npz")) == ["Robot1-w20-s10-seed0-p5-guess.npz",
                                                                           "Robot1-w20-s10-seed0-p5.npz"]
    capsys.readouterr()
    before = dict(calls)
    got = _both(long, noise, args)                # the same files, another log: computed again
    assert calls == {k: v + 1 for k, v in before.items()}
    assert len(got[0]) == len(long.sighting_times)
    _same(got, expected)
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "Robot1-w20-s10-seed0-p5.npz" in err[0] and "-guess.npz" in err[1], err
    assert all("computed again" in line for line in err)

    before = dict(calls)
    again = _both(long, noise, args)              # the entries now hold the long log's: used
    assert calls == before
    _same(again, expected)
    assert capsys.readouterr().err == ""


def test_an_entry_made_with_another_noise_model_is_computed_again(folder, _filled, tmp_path, calls, capsys):
    log = read_mrclam(folder, 1, until=60.0)
    args = _filled_cache(_filled, tmp_path)       # filled with _noise(0.02)
    before = dict(calls)
    _both(log, _noise(0.05), args)
    assert calls == {k: v + 1 for k, v in before.items()}
    assert len(capsys.readouterr().err.splitlines()) == 2


def test_a_guess_of_other_names_is_computed_again(folder, _filled, tmp_path, calls):
    log = read_mrclam(folder, 1, until=60.0)
    noise, args = _noise(), _filled_cache(_filled, tmp_path)     # the names' and their guess's entries
    names = _filled[1].names
    other = np.where(names == names.max(), -1, names)       # a name left out
    before = calls["names_guess"]
    poses, guess = mc._guess(log, other, noise, CONFIG, args)
    assert calls["names_guess"] == before + 1
    assert int(names.max()) not in guess


def test_an_entry_without_a_digest_is_not_trusted(folder, _filled, tmp_path, calls, capsys):
    log = read_mrclam(folder, 1, until=60.0)
    noise, args = _noise(), _filled_cache(_filled, tmp_path)
    names = _filled[1]
    path = next((tmp_path / "cache").rglob("*-p5.npz"))
    # as the cache was written before its entries held a digest, and wrong: every sighting under one name
    np.savez(path, names=np.zeros_like(names.names), row=np.array('{"robot": "stale"}'))
    before = calls["chain_log"]
    again, row_again = cn._chained(log, args, noise, CONFIG)
    assert calls["chain_log"] == before + 1
    np.testing.assert_array_equal(again.names, names.names)
    assert row_again["robot"] == log.name
    assert "computed again" in capsys.readouterr().err


def test_the_chain_s_command_with_a_cache_of_a_shorter_log_ends_as_without_a_cache(folder, tmp_path, monkeypatch,
                                                                                   capsys):
    """mrclam_constellation.main with ``--names-cache``, the log read to 60 s and then to 90 s (as tests and scripts
    read a log's first part, by patching the module's read_mrclam): the 90-s run ends as one without a cache."""
    import io
    import json
    from contextlib import redirect_stdout

    from estimation.noise_model import NoiseModel

    model = tmp_path / "model.toml"
    _noise().save(model)
    assert NoiseModel.load(model) == _noise()

    def chain(until, *cache):
        log = read_mrclam(folder, 1, until=until)
        monkeypatch.setattr(mc, "read_mrclam", lambda data, robot: log)
        out = io.StringIO()
        with redirect_stdout(out):
            assert mc.main(["--data", str(folder), "--robots", "1", "--particles", "5", "--window", "20",
                            "--max-rounds", "1", "--noise", str(model), "--json", *cache]) == 0
        return _without_cpu(json.loads(out.getvalue().strip().splitlines()[-1]))

    cache = ["--names-cache", str(tmp_path / "cache")]
    chain(60.0, *cache)
    capsys.readouterr()
    assert chain(90.0, *cache) == chain(90.0)
    assert capsys.readouterr().err.count("computed again") == 2


def _without_cpu(x):
    if isinstance(x, dict):
        return {k: _without_cpu(v) for k, v in x.items() if "cpu" not in k}
    if isinstance(x, list):
        return [_without_cpu(v) for v in x]
    return x
