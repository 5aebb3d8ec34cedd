"""The robot parameter-file reader against nonsense: one line naming the file, line and field; fuzzed files
give a clean BadFileError or a valid parameter set, memory bounded."""
from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.arcos.params import BUILTIN_DIR, load_params
from drivers.errors import BadFileError

from .memory import read_bounded

GOOD = json.loads((BUILTIN_DIR / "p3at-sh.json").read_text())


@pytest.mark.parametrize("text, problem", [
    ("[" * 100_000, "nested too deeply"),
    ('{"DistConvFactor": ' + "9" * 5000 + "}", "not valid JSON"),
    (json.dumps({**GOOD, "DistConvFactor": 1e300}), "field 'DistConvFactor': 1e+300 is beyond"),
    (json.dumps({**GOOD, "sonar_poses": [[0, 0, 0]] * 300}), "at most 256"),
    (json.dumps({**GOOD, "sonar_poses": [[0, 0, "x" * 10_000]]}), "entry 0 must be"),
])
def test_bad_parameter_files_are_one_short_line(tmp_path, text, problem) -> None:
    path = tmp_path / "p.json"
    path.write_text(text)
    with pytest.raises(BadFileError) as info:
        load_params(path)
    message = str(info.value)
    assert message.startswith(f"{path}:") and problem in message and len(message) < 300


def test_an_oversized_parameter_file_is_refused_before_reading(tmp_path) -> None:
    path = tmp_path / "big.json"
    with open(path, "wb") as f:
        f.truncate(2 << 20)
    with pytest.raises(BadFileError, match="a parameter file has at most"):
        read_bounded(lambda: load_params(path), ())


leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**30, 10**30), st.floats(), st.text(max_size=4),
                 st.lists(st.floats(), max_size=4))


@settings(max_examples=100, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(sorted(GOOD)), leaf, st.binary(max_size=20), st.integers(0, 2000))
def test_fuzz_parameter_files(tmp_path, key, value, junk, at) -> None:
    text = json.dumps({**GOOD, key: value}).encode()
    if junk:
        text = text[:at] + junk + text[at + len(junk):]
    path = tmp_path / "p.json"
    path.write_bytes(text)
    params = read_bounded(lambda: load_params(path), BadFileError)
    if params is not None:
        assert params.dist_conv_factor > 0 and len(params.sonar_poses) <= 256
