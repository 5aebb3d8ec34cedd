"""A noise model the reader accepts is one the writer can write back, and what it writes reads back the same
(session 44, A).

`p3at slam noise --self-calibrate --noise FILE` writes the given model out again with its [fit] figures. A [fit]
holding a TOML datetime, an inline table, an array of tables or ``nan`` loaded, then failed at the write after the
calibration's work (12-22 s on MRCLAM robot 1) with "p3at slam noise: cannot write datetime values to TOML", naming
no file; a [fit] key needing quotes (``"a b" = 1``) or text holding a control character (``robot = "a\\u0001b"``)
was written as a file no TOML reader takes. The reader now refuses such a [fit] up front, naming file and key, and
the writer escapes every control character."""
from __future__ import annotations

import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.noise_model import P3AT_VIDERE_DEFAULT, NoiseModel, NoiseModelError

REPO = Path(__file__).resolve().parents[2]
MRCLAM = REPO.parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"

scalars = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**63, 2**63), st.booleans(),
                    st.text(max_size=8), st.datetimes(), st.dates(), st.times())
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                        st.dictionaries(st.text(max_size=3), inner, max_size=2)),
                      max_leaves=6)


def _base() -> dict:
    return tomllib.loads(P3AT_VIDERE_DEFAULT.to_toml())


def _writable(value) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, bool | int | str):
        return True
    if isinstance(value, list):
        return all(_writable(v) for v in value)
    return False   # datetimes, dates, times, tables


@settings(max_examples=200, deadline=None)
@given(fit=st.dictionaries(st.text(min_size=1, max_size=6), values, max_size=4),
       robot=st.text(max_size=10))
def test_what_loads_writes_back_and_reads_back_the_same(fit, robot):
    data = _base() | {"fit": fit, "robot": robot}
    accepted = all(_writable(v) for v in fit.values()) and all(re.fullmatch(r"[A-Za-z0-9_-]+", k) for k in fit)
    if not accepted:
        with pytest.raises(NoiseModelError) as error:
            NoiseModel.from_dict(data, "model.toml")
        assert str(error.value).startswith("model.toml: [fit] ") and "\n" not in str(error.value)
        return
    model = NoiseModel.from_dict(data, "model.toml")
    again = NoiseModel.from_dict(tomllib.loads(model.to_toml()), "written")
    assert again == model and again.robot == robot


@pytest.mark.parametrize(("line", "words"), [
    ("when = 1979-05-27T07:32:00Z", "[fit] when: cannot write datetime"),
    ("table = {a = 1}", "[fit] table: cannot write dict"),
    ("figure = nan", "[fit] figure: cannot write the non-finite value nan"),
    ('"a b" = 1', "[fit] key 'a b' is not a bare key"),
])
def test_a_fit_the_writer_cannot_write_is_refused_on_load(tmp_path, line, words):
    text = P3AT_VIDERE_DEFAULT.to_toml() + f"\n[fit]\n{line}\n"
    path = tmp_path / "noise.toml"
    path.write_text(text)
    with pytest.raises(NoiseModelError) as error:
        NoiseModel.load(path)
    assert str(error.value).startswith(str(path)) and words in str(error.value), str(error.value)


def test_control_characters_in_text_are_written_so_that_they_read_back(tmp_path):
    model = NoiseModel(P3AT_VIDERE_DEFAULT.odometry, stereo=P3AT_VIDERE_DEFAULT.stereo, robot="a\x01b\rc\x7f",
                       fit={"note": "x\x1by"})
    model.save(tmp_path / "m.toml")
    assert NoiseModel.load(tmp_path / "m.toml") == model


@pytest.mark.skipif(not MRCLAM.is_dir(), reason="MRCLAM data set not available")
def test_self_calibrate_refuses_such_a_model_before_its_work(tmp_path):
    """The command: one line naming the file and key, exit 2, nothing written (before: after the work, no file)."""
    noise = tmp_path / "given.toml"
    noise.write_text(P3AT_VIDERE_DEFAULT.to_toml() + "\n[fit]\nwhen = 1979-05-27T07:32:00Z\n")
    out = tmp_path / "out.toml"
    done = subprocess.run([sys.executable, "-m", "runtime.cli", "slam", "noise", "mrclam", str(MRCLAM), "--robot",
                           "1", "--self-calibrate", "--noise", str(noise), "--out", str(out)], cwd=REPO,
                          capture_output=True, text=True, timeout=600)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and str(noise) in lines[0] and "[fit] when" in lines[0], lines
    assert not out.exists()
