"""The spread of a map's own sightings of each landmark (estimation.sighting_spread) and its map-file field."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from estimation.errors import MapFileError
from estimation.geometry import between, transform_points
from estimation.landmark_map import LandmarkMap
from estimation.sighting_spread import SightingRecorder

_finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


def _sightings(seed: int, n_landmarks: int, n_frames: int, offsets: np.ndarray | None = None):
    """A map of ``n_landmarks`` with a random planar trajectory; every frame sees every landmark, the sighting
    expressed in the robot's frame (base_link) at that frame's pose, displaced in the map's frame by ``offsets``
    (n_frames, n_landmarks, 3) when given."""
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.uniform(-20, 20, size=(n_landmarks, 2)), rng.uniform(-1, 1, n_landmarks)])
    t = np.sort(rng.uniform(0, 100, n_frames)) + np.arange(n_frames)     # distinct times
    poses = np.column_stack([rng.uniform(-20, 20, size=(n_frames, 2)), rng.uniform(-np.pi, np.pi, n_frames)])
    m = LandmarkMap(x, np.tile(np.eye(3) * 0.01, (n_landmarks, 1, 1)), np.zeros((n_landmarks, 0), np.float32),
                    ids=rng.permutation(1000)[:n_landmarks], trajectory=np.column_stack([t, poses]))
    recorder = SightingRecorder()
    for k in range(n_frames):
        world = x + (0 if offsets is None else offsets[k])
        local = transform_points(between(poses[k], np.zeros(3)), world)       # the map frame into the robot's
        recorder.add(t[k], local, m.ids)
    return m, recorder


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 8), frames=st.integers(1, 12))
def test_sightings_that_agree_with_the_map_have_no_spread(seed, n, frames):
    m, recorder = _sightings(seed, n, frames)
    np.testing.assert_allclose(recorder.covariances(m), 0.0, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 8), frames=st.integers(1, 12))
def test_the_spread_is_the_mean_outer_product_of_the_sightings_offsets_in_the_maps_frame(seed, n, frames):
    offsets = np.random.default_rng(seed + 1).normal(scale=0.3, size=(frames, n, 3))
    m, recorder = _sightings(seed, n, frames, offsets)
    expected = np.einsum("kni,knj->nij", offsets, offsets) / frames
    np.testing.assert_allclose(recorder.covariances(m), expected, atol=1e-9)


def test_sightings_of_other_landmarks_or_at_times_off_the_trajectory_are_left_out():
    offsets = np.random.default_rng(3).normal(scale=0.3, size=(4, 2, 3))
    m, recorder = _sightings(3, 2, 4, offsets)
    expected = recorder.covariances(m)
    recorder.add(m.trajectory[1, 0], np.ones((1, 3)) * 50, [int(m.ids.max()) + 1])    # not one of the map's
    recorder.add(m.trajectory[1, 0] + 0.5, np.ones((2, 3)) * 50, m.ids)               # no pose at that time
    recorder.add(m.trajectory[1, 0], np.ones((1, 3)) * 50, [-1])                      # given to no landmark
    np.testing.assert_allclose(recorder.covariances(m), expected, atol=1e-12)


@st.composite
def _maps_with_spread(draw) -> LandmarkMap:
    n = draw(st.integers(0, 12))
    x = draw(arrays(np.float64, (n, 3), elements=_finite))
    g = draw(arrays(np.float64, (n, 3, 3), elements=st.floats(-2, 2, allow_nan=False)))
    return LandmarkMap(x, np.tile(np.eye(3) * 0.01, (n, 1, 1)), np.zeros((n, 4), np.float32), robot="r1",
                       sighting_covariances=g @ np.swapaxes(g, 1, 2))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=_maps_with_spread())
def test_the_spread_survives_a_round_trip_and_a_subset(tmp_path: Path, m: LandmarkMap) -> None:
    m.save(tmp_path / "m.npz")
    back = LandmarkMap.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.sighting_covariances, m.sighting_covariances)
    assert back.drift_covariances is None
    keep = np.arange(len(m)) % 2 == 0
    np.testing.assert_array_equal(back.subset(keep).sighting_covariances, m.sighting_covariances[keep])


def test_a_file_without_the_spread_reads_as_before(tmp_path: Path) -> None:
    m = LandmarkMap(np.zeros((3, 3)), np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 2), np.float32))
    m.save(tmp_path / "old.npz")
    with np.load(tmp_path / "old.npz") as z:
        assert "sighting_covariances" not in z.files
    assert LandmarkMap.load(tmp_path / "old.npz").sighting_covariances is None


@pytest.mark.parametrize("value, message", [
    (np.zeros((2, 3, 3)), "'sighting_covariances' has shape (2, 3, 3), expected (3, 3, 3)"),
    (np.tile(-np.eye(3), (3, 1, 1)), "'sighting_covariances[0]' is not positive semi-definite"),
    (np.tile(np.triu(np.ones((3, 3))), (3, 1, 1)), "'sighting_covariances[0]' is not symmetric"),
    (np.full((3, 3, 3), np.inf), "'sighting_covariances' holds non-finite values"),
])
def test_a_bad_spread_is_one_line_naming_it(tmp_path: Path, value, message) -> None:
    LandmarkMap(np.zeros((3, 3)), np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 2), np.float32)).save(tmp_path / "m.npz")
    with np.load(tmp_path / "m.npz") as z:
        members = {k: z[k] for k in z.files}
    np.savez(tmp_path / "bad.npz", **members, sighting_covariances=value)
    with pytest.raises(MapFileError) as err:
        LandmarkMap.load(tmp_path / "bad.npz")
    assert message in str(err.value) and "\n" not in str(err.value)
