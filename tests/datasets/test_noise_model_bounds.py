"""A noise model's magnitudes are bounded where a value stops describing a robot or a sensor.

Before session 23 a file holding ``range_sigma_m = 1e308`` (or ``max_range_m``) ended ``p3at slam dataset`` in an
internal OverflowError (exit 70), ``xy_var_per_m = 1e308`` in dozens of RuntimeWarnings, ``heading_drift_tau_s =
1e308`` in an error naming neither file nor key. Now every bounded key refuses a value beyond its bound in one line
naming the file and the key, and a model at every bound at once still runs the filter without a warning."""
from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.noise_model import (
    MAGNITUDE_BOUNDS,
    NoiseModel,
    NoiseModelError,
    OdometryNoise,
    RangeBearingNoise,
    StereoNoise,
)

SECTIONS = {"odometry": OdometryNoise, "range_bearing": RangeBearingNoise, "stereo": StereoNoise}


def _base() -> NoiseModel:
    return NoiseModel(OdometryNoise(1e-3, 1e-3, 1e-3, heading_drift_sigma_per_m=0.1, heading_drift_tau_s=10.0),
                      RangeBearingNoise(0.05, 0.01, 0.02), StereoNoise(0.3, 0.3, 0.2))


def _section_of(key: str) -> str:
    return next(name for name, kind in SECTIONS.items() if key in kind.__dataclass_fields__)


@settings(max_examples=60, deadline=None)
@given(key=st.sampled_from(sorted(MAGNITUDE_BOUNDS)), factor=st.floats(1.0 + 1e-9, 1e300),
       sign=st.sampled_from([1, -1]))
def test_a_value_beyond_its_bound_is_refused_naming_the_file_and_the_key(key, factor, sign):
    model, section = _base(), _section_of(key)
    data = {"format": "p3at-noise-model", "version": 1}
    data |= {name: dict(vars(getattr(model, name))) for name in SECTIONS}
    data[section][key] = sign * MAGNITUDE_BOUNDS[key] * factor
    with pytest.raises(NoiseModelError) as refused:
        NoiseModel.from_dict(data, "n.toml")
    message = str(refused.value)
    assert message.startswith("n.toml: ") and key in message and "\n" not in message


@pytest.mark.parametrize("key", sorted(MAGNITUDE_BOUNDS))
def test_the_bound_itself_is_a_valid_value(key):
    model, section = _base(), _section_of(key)
    fields = dict(vars(getattr(model, section))) | {key: MAGNITUDE_BOUNDS[key]}
    replace(model, **{section: SECTIONS[section](**fields)})


def test_a_model_at_every_bound_runs_the_filter_without_a_warning(tmp_path, synthetic):
    synthetic.write(tmp_path, seconds=20.0)
    log = read_mrclam(tmp_path, 1)
    b = MAGNITUDE_BOUNDS
    odometry = OdometryNoise(b["xy_var_per_m"], b["theta_var_per_rad"], b["theta_var_per_m"],
                             heading_drift_sigma_per_m=1.0, heading_drift_tau_s=b["heading_drift_tau_s"])
    sensor = RangeBearingNoise(b["range_sigma_m"], b["range_sigma_per_m"], b["bearing_sigma_rad"],
                               bearing_offset_rad=0.0, max_range_m=b["max_range_m"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run = run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(0),
                               noise=NoiseModel(odometry, sensor), association="id")
    assert np.isfinite(run.metrics["ate_m"]) and np.all(np.isfinite(run.map.positions))
