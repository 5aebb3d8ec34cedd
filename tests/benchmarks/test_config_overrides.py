"""The benchmarks' one ``--set FIELD=VALUE`` parser: every field's type, both spellings of the docs, bad items."""
from __future__ import annotations

from dataclasses import fields, replace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.config_overrides import config_overrides
from estimation.fastslam import FastSLAMConfig

DEFAULTS = FastSLAMConfig()
FLOAT_FIELDS = [f.name for f in fields(FastSLAMConfig) if type(getattr(DEFAULTS, f.name)) is float]
INT_FIELDS = [f.name for f in fields(FastSLAMConfig) if type(getattr(DEFAULTS, f.name)) is int]
BOOL_FIELDS = [f.name for f in fields(FastSLAMConfig) if type(getattr(DEFAULTS, f.name)) is bool]
STR_FIELDS = [f.name for f in fields(FastSLAMConfig) if type(getattr(DEFAULTS, f.name)) is str]


@given(st.sampled_from(FLOAT_FIELDS), st.floats(allow_nan=False))
def test_a_float_field_reads_back_the_number_written(name, value):
    assert config_overrides([f"{name}={value!r}"]) == {name: value}


@given(st.sampled_from(INT_FIELDS), st.integers(-10**6, 10**6))
def test_an_int_field_reads_back_the_number_written(name, value):
    parsed = config_overrides([f"{name}={value}"])
    assert parsed == {name: value} and type(parsed[name]) is int


@given(st.sampled_from(BOOL_FIELDS), st.sampled_from(["true", "True", "1", "yes", "false", "FALSE", "0", "no"]))
def test_a_bool_field_takes_the_usual_spellings(name, text):
    assert config_overrides([f"{name}={text}"]) == {name: text.lower() in ("true", "1", "yes")}


@pytest.mark.parametrize("name", STR_FIELDS)
def test_a_string_field_is_read_bare_or_json_quoted_and_builds_a_config(name):
    value = getattr(DEFAULTS, name)
    assert config_overrides([f"{name}={value}"]) == config_overrides([f'{name}="{value}"']) == {name: value}
    assert replace(DEFAULTS, **config_overrides([f"{name}={value}"])) == DEFAULTS


def test_a_tuple_field_takes_a_json_list():
    assert config_overrides(["sensor_offset=[0.1, 0, 0.4]"]) == {"sensor_offset": (0.1, 0.0, 0.4)}


def test_later_items_win_and_several_fields_combine():
    assert config_overrides(["max_observations=40", "merge_look=newer", "max_observations=0"]) == {
        "max_observations": 0, "merge_look": "newer"}


@pytest.mark.parametrize("item, says", [
    ("no_such_field=1", "FastSLAMConfig has no field 'no_such_field'"),
    ("max_observations", "give FIELD=VALUE"),
    ("max_observations=4.5", "invalid literal for int()"),
    ("id_drift_inherit=maybe", "give true or false"),
    ("sensor_offset=0.1", "give a JSON list"),
    ("merge_descriptor_threshold=high", "could not convert string to float"),
])
def test_a_bad_item_stops_with_one_line_naming_it(item, says):
    with pytest.raises(SystemExit) as stop:
        config_overrides([item])
    message = str(stop.value.code)
    assert "\n" not in message and repr(item) in message and says in message
