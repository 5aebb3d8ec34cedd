"""The map file's optional drift fields (drift_covariances, drift_origins): round trip, old files, bad input."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from estimation.errors import MapFileError
from estimation.landmark_map import LandmarkMap

_finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@st.composite
def _drifting_maps(draw) -> LandmarkMap:
    n = draw(st.integers(0, 12))
    x = draw(arrays(np.float64, (n, 3), elements=_finite))
    g = draw(arrays(np.float64, (n, 3, 3), elements=st.floats(-2, 2, allow_nan=False)))
    origins = draw(arrays(np.float64, (n, 2), elements=_finite))
    return LandmarkMap(x, np.tile(np.eye(3) * 0.01, (n, 1, 1)), np.zeros((n, 4), np.float32), robot="r1",
                       drift_covariances=g @ np.swapaxes(g, 1, 2), drift_origins=origins)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=_drifting_maps())
def test_the_drift_fields_survive_a_round_trip_and_a_subset(tmp_path: Path, m: LandmarkMap) -> None:
    m.save(tmp_path / "m.npz")
    back = LandmarkMap.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.drift_covariances, m.drift_covariances)
    np.testing.assert_array_equal(back.drift_origins, m.drift_origins)
    keep = np.arange(len(m)) % 2 == 0
    part = back.subset(keep)
    np.testing.assert_array_equal(part.drift_covariances, m.drift_covariances[keep])
    np.testing.assert_array_equal(part.drift_origins, m.drift_origins[keep])


def test_a_file_without_the_drift_reads_as_before(tmp_path: Path) -> None:
    m = LandmarkMap(np.zeros((3, 3)), np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 2), np.float32))
    m.save(tmp_path / "old.npz")
    with np.load(tmp_path / "old.npz") as z:
        assert "drift_covariances" not in z.files
    back = LandmarkMap.load(tmp_path / "old.npz")
    assert back.drift_covariances is None and back.drift_origins is None


def _rewrite(tmp_path: Path, **changes) -> Path:
    m = LandmarkMap(np.zeros((3, 3)), np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 2), np.float32),
                    drift_covariances=np.tile(np.eye(3) * 0.1, (3, 1, 1)), drift_origins=np.zeros((3, 2)))
    m.save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz") as z:
        members = {k: z[k] for k in z.files}
    members.update(changes)
    members = {k: v for k, v in members.items() if v is not None}
    np.savez(tmp_path / "bad.npz", **members)
    return tmp_path / "bad.npz"


@pytest.mark.parametrize("changes, message", [
    ({"drift_origins": None}, "'drift_origins' is missing"),
    ({"drift_covariances": None}, "'drift_covariances' is missing"),
    ({"drift_origins": np.zeros((2, 2))}, "'drift_origins' has shape (2, 2), expected (3, 2)"),
    ({"drift_covariances": np.tile(-np.eye(3), (3, 1, 1))}, "'drift_covariances[0]' is not positive semi-definite"),
    ({"drift_covariances": np.tile(np.triu(np.ones((3, 3))), (3, 1, 1))}, "'drift_covariances[0]' is not symmetric"),
    ({"drift_origins": np.full((3, 2), np.nan)}, "'drift_origins' holds non-finite values"),
])
def test_a_bad_drift_field_is_one_line_naming_it(tmp_path: Path, changes, message) -> None:
    with pytest.raises(MapFileError) as err:
        LandmarkMap.load(_rewrite(tmp_path, **changes))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_one_drift_field_without_the_other_is_refused_in_memory_too() -> None:
    with pytest.raises(ValueError, match="both or neither"):
        LandmarkMap(np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 0), np.float32), drift_origins=np.zeros((1, 2)))
