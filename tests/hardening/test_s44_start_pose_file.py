"""`p3at fuse --start-poses FILE.json` with σ of the wrong type, keys given twice or misspelt (session 44, A).

Before: ``"sigma_xy": NaN`` or ``Infinity`` read as "no σ given" (then "the start of map '0' has no standard
deviations: give them in it", of a file that gave them), ``true`` as 1 m and ``"1"`` as 1 m, a misspelt key
(``"sigma": 1``) and a σ given without the other were dropped in silence, and a start given twice kept the last
one. Each is now one line naming the file and the key; the file's valid forms read as before."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fusion.errors import IncompatibleMapsError
from fusion.prior import MAX_START_SIGMA, load_starts

STARTS = '"starts": {"robot1": [0, 0, 0], "robot2": [1.5, 0, 3.1]}'


def _file(tmp_path, text: str):
    path = tmp_path / "starts.json"
    path.write_text(text)
    return path


def _refused(path, *words):
    with pytest.raises(IncompatibleMapsError) as error:
        load_starts(str(path))
    message = str(error.value)
    assert message.startswith(str(path)) and "\n" not in message and all(w in message for w in words), message


@pytest.mark.parametrize("value", ["NaN", "Infinity", "-Infinity", "true", "false", '"1"', "[1]", "null", "{}",
                                   "0", "-1", "1e999", "9" * 400])
def test_a_sigma_that_is_not_a_positive_finite_number_is_refused_by_name(tmp_path, value):
    _refused(_file(tmp_path, f'{{"sigma_xy": {value}, "sigma_yaw": 0.3, {STARTS}}}'), "sigma_xy")
    _refused(_file(tmp_path, f'{{"sigma_xy": 1, "sigma_yaw": {value}, {STARTS}}}'), "sigma_yaw")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30), st.booleans(),
                       st.none(), st.text(max_size=5), st.lists(st.integers(), max_size=2)))
def test_any_json_sigma_gives_the_value_or_one_line(tmp_path, value):
    """A number in the prior's range is taken as given; anything else is one line naming the key."""
    path = _file(tmp_path, json.dumps({"sigma_xy": value, "sigma_yaw": 0.3, "starts": {"a": [0, 0, 0]}}))
    good = (isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            and 0 < value <= MAX_START_SIGMA)
    if good:
        (pose, sigmas), = load_starts(str(path)).values()
        assert sigmas == (float(value), 0.3) and np.array_equal(pose, [0, 0, 0])
    else:
        with pytest.raises(IncompatibleMapsError, match="sigma_xy"):
            load_starts(str(path))


def test_keys_given_twice_misspelt_or_alone_are_refused(tmp_path):
    _refused(_file(tmp_path, '{"sigma_xy": 1, "sigma_yaw": 0.3, "starts": {"a": [0, 0, 0], "a": [1, 0, 0]}}'),
             "'a' appears twice")
    _refused(_file(tmp_path, f'{{"sigma_xy": 1, "sigma_xy": 2, "sigma_yaw": 0.3, {STARTS}}}'),
             "'sigma_xy' appears twice")
    _refused(_file(tmp_path, f'{{"sigma": 1, {STARTS}}}'), "unknown key(s) sigma")
    _refused(_file(tmp_path, f'{{"sigma_xy": 1, {STARTS}}}'), "sigma_xy without sigma_yaw")
    _refused(_file(tmp_path, f'{{"sigma_yaw": 0.3, {STARTS}}}'), "sigma_yaw without sigma_xy")


def test_the_valid_forms_read_as_before(tmp_path):
    starts = load_starts(str(_file(tmp_path, '{"sigma_xy": 1, "sigma_yaw": 0.3, "starts": {"robot1": [0, 0, 0], '
                                             '"robot2": [1.5, 0, 3.1, 0.5, 0.1], "2": "1,2,0.5"}}')))
    assert starts["robot1"][1] == (1.0, 0.3) and starts["robot2"][1] == (0.5, 0.1)
    assert np.allclose(starts["2"][0], [1, 2, 0.5]) and starts["2"][1] == (1.0, 0.3)
    alone = load_starts(str(_file(tmp_path, f"{{{STARTS}}}")))   # no σ in the file: the caller's (--start-sigma)
    assert all(sigmas is None for _, sigmas in alone.values())
