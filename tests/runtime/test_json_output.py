"""The CLI's --json outputs are strict JSON: a figure that could not be computed is null, never NaN or Infinity (jq
and other strict parsers refuse those). The helper by hypothesis over nested values; `p3at slam dataset --json` end
to end on a run too short for any landmark score (the synthetic MRCLAM log)."""
from __future__ import annotations

import json
import math

from hypothesis import given
from hypothesis import strategies as st

from runtime.json_output import finite_or_null, json_text
from tests.datasets.conftest import run_cli, write_mrclam
from tests.datasets.test_no_ground_truth import _noise

VALUES = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
                      lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner,
                                                                                    max_size=4),
                      max_leaves=20)


def _strict(text: str):
    def refuse(constant):
        raise ValueError(f"not strict JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


def _same(read, value) -> None:
    """``read`` (parsed output) is ``value`` with every non-finite float null and tuples as lists."""
    if isinstance(value, float):
        assert read == (value if math.isfinite(value) else None)
    elif isinstance(value, dict):
        assert list(read) == list(value)
        for k in value:
            _same(read[k], value[k])
    elif isinstance(value, (list, tuple)):
        assert len(read) == len(value)
        for a, b in zip(read, value, strict=True):
            _same(a, b)
    else:
        assert read == value


@given(VALUES)
def test_any_value_is_strict_json_with_non_finite_floats_null(value):
    _same(_strict(json_text(value)), value)
    _same(finite_or_null(value), value)


def test_slam_dataset_json_of_a_run_too_short_to_score_landmarks_says_null(tmp_path):
    write_mrclam(tmp_path / "data", seconds=10.0)
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                               str(tmp_path / "m.npz"), "--particles", "5", "--noise", str(_noise(tmp_path)),
                               "--until", "0.1", "--no-smooth", "--json")
    assert status == 0, err
    scores = _strict(out)
    assert scores["landmark_error_median_m"] is None and scores["pose_nees_median"] is None
    assert isinstance(scores["ate_m"], float) and math.isfinite(scores["ate_m"])
