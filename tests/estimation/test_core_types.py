"""The shared estimation types: planar geometry, the observation set and the landmark-map file format."""
from __future__ import annotations

import io
import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation.errors import MapFileError
from estimation.geometry import between, compose, inverse, pose_to_matrix, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap
from estimation.observations import StereoObservations

coord = st.floats(-50, 50, allow_nan=False)
angle = st.floats(-10, 10, allow_nan=False)
poses = st.tuples(coord, coord, angle).map(np.array)


def _same_pose(a, b, tol=1e-9):
    return np.allclose(a[:2], b[:2], atol=tol) and abs(wrap_angle(a[2] - b[2])) < tol


@given(poses, poses, poses)
def test_compose_is_associative(a, b, c):
    assert _same_pose(compose(compose(a, b), c), compose(a, compose(b, c)))


@given(poses, poses)
def test_between_undoes_compose(a, b):
    assert _same_pose(between(a, compose(a, b)), b)
    assert _same_pose(compose(a, inverse(a)), np.zeros(3))


@given(poses, st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=5).map(np.array))
def test_transform_points_matches_the_homogeneous_matrix(pose, points):
    homogeneous = np.c_[points, np.ones(len(points))] @ pose_to_matrix(pose).T
    assert np.allclose(transform_points(pose, points), homogeneous[:, :3])


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_angle_range(theta):
    w = wrap_angle(theta)
    assert -np.pi <= w < np.pi and np.isclose(np.sin(w), np.sin(theta), atol=1e-6)


def test_observation_arrays_must_agree():
    with pytest.raises(ValueError, match="inconsistent"):
        StereoObservations(np.zeros((3, 3)), np.zeros((2, 3, 3)), np.zeros((3, 64), np.float32))
    assert len(StereoObservations.empty()) == 0


def _map(n=5, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 64)).astype(np.float32)
    return LandmarkMap(rng.normal(size=(n, 3)), np.tile(np.eye(3) * 0.01, (n, 1, 1)),
                       d / np.linalg.norm(d, axis=1, keepdims=True), robot="r1",
                       metadata={"true_start_pose": [1.0, 2.0, 0.5]})


def test_map_round_trip_and_ply(tmp_path):
    original = _map()
    original.save(tmp_path / "m.npz")
    loaded = LandmarkMap.load(tmp_path / "m.npz")
    for field in ("positions", "covariances", "descriptors", "ids", "counts", "seen_by"):
        assert np.array_equal(getattr(loaded, field), getattr(original, field))
    assert (loaded.robot, loaded.robots, loaded.metadata) == ("r1", ["r1"], original.metadata)
    original.export_ply(tmp_path / "m.ply")
    assert "element vertex 5" in (tmp_path / "m.ply").read_text()


def _rewrite(path, **changes):
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    arrays = {k: v for k, v in arrays.items() if v is not None}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())


def _json(obj):
    return np.frombuffer(json.dumps(obj).encode(), np.uint8)


@pytest.mark.parametrize("changes, message", [
    ({"format": _json({"format": "p3at-landmark-map", "version": 99})}, "version 99 is not supported"),
    ({"format": _json({"format": "something-else", "version": 1})}, "field 'format'"),
    ({"covariances": np.zeros((4, 3, 3))}, "field 'covariances' has shape"),
    ({"positions": np.full((5, 3), np.nan)}, "field 'positions' holds non-finite"),
    ({"ids": np.zeros(5, np.int64)}, "duplicate landmark ids"),
    ({"meta": np.frombuffer(b"{not json", np.uint8)}, "field 'meta' is not valid JSON"),
    ({"descriptors": None}, "field 'descriptors' is missing"),
])
def test_defective_map_files_name_the_file_and_field(tmp_path, changes, message):
    path = tmp_path / "bad.npz"
    _map().save(path)
    _rewrite(path, **changes)
    with pytest.raises(MapFileError, match=message) as info:
        LandmarkMap.load(path)
    assert "bad.npz" in str(info.value)


def test_non_archive_and_missing_files(tmp_path):
    (tmp_path / "text.npz").write_text("hello")
    with pytest.raises(MapFileError, match="not an npz archive"):
        LandmarkMap.load(tmp_path / "text.npz")
    with pytest.raises(MapFileError, match="no such map file"):
        LandmarkMap.load(tmp_path / "absent.npz")


def test_save_is_atomic_and_leaves_no_temporary_files(tmp_path):
    _map().save(tmp_path / "m.npz")
    _map(seed=1).save(tmp_path / "m.npz")  # overwrite in place
    assert [p.name for p in tmp_path.iterdir()] == ["m.npz"]
    assert np.array_equal(LandmarkMap.load(tmp_path / "m.npz").positions, _map(seed=1).positions)


def test_saved_files_get_ordinary_permissions(tmp_path):
    import os
    _map().save(tmp_path / "m.npz")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "m.npz").stat().st_mode & 0o777 == 0o666 & ~umask
