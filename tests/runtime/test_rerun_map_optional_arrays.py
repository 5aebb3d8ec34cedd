"""A map extracted from a recording is the map file, field by field, with the arrays only some maps have: the drift
(``drift_covariances``, ``drift_origins``) and the sightings' scatter (``sighting_covariances``) that
``fuse_all(calibration="drift" / "sightings")`` uses. Before session 15 the snapshots left them out, so a map that
`p3at review` extracted lacked them. A snapshot without them (a recording written before) still reads; the
snapshot's CRC-32 covers them."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from runtime.cli import main
from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording
from tests.runtime.rerun_helpers import landmark_map
from tests.runtime.test_rerun_map_checksum import _flip_in

FIELDS = ("positions", "covariances", "descriptors", "ids", "counts", "seen_by", "trajectory", "robot", "frame",
          "robots", "metadata", "drift_covariances", "drift_origins", "sighting_covariances")


def _with_optional(m: LandmarkMap, rng: np.random.Generator, drift: bool = True, sightings: bool = True):
    n = len(m)
    a = rng.normal(size=(n, 3, 3)) * 0.05
    if drift:
        m.drift_covariances = a @ np.swapaxes(a, 1, 2) + 1e-4 * np.eye(3)
        m.drift_origins = rng.uniform(-5, 5, (n, 2))
    if sightings:
        b = rng.normal(size=(n, 3, 3)) * 0.02
        m.sighting_covariances = b @ np.swapaxes(b, 1, 2) + 1e-5 * np.eye(3)
    return m


def _recording(path, snapshots, key: str = "robot1"):
    log = MissionLog(open_recording(str(path)), ["robot1"])
    for t, m in enumerate(snapshots):
        log.log_map(key, float(t), m)
        log.flush()     # one message per snapshot, in order
    log.close()


def _assert_same(got: LandmarkMap, expected: LandmarkMap) -> None:
    for f in FIELDS:
        a, b = getattr(got, f), getattr(expected, f)
        if b is None or a is None:
            assert a is None and b is None, f
        elif isinstance(b, np.ndarray):
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), f
        else:
            assert a == b, f


def test_a_map_extracted_by_review_is_the_map_file_field_by_field(tmp_path, capsys):
    m = _with_optional(landmark_map("robot1", 25, np.random.default_rng(0)), np.random.default_rng(1))
    m.metadata = {"note": "a robot's map"}
    m.save(tmp_path / "robot1.npz")
    saved = LandmarkMap.load(tmp_path / "robot1.npz")
    _recording(tmp_path / "mission.rrd", [saved])
    assert main(["review", str(tmp_path / "mission.rrd"), "--export", str(tmp_path / "maps")]) == 0
    _assert_same(LandmarkMap.load(tmp_path / "maps" / "robot1.npz"), saved)
    assert saved.drift_covariances is not None and saved.sighting_covariances is not None


@settings(max_examples=12, deadline=None)
@given(n=st.integers(0, 6), drift=st.booleans(), sightings=st.booleans(), seed=st.integers(0, 2**16))
def test_each_optional_array_is_read_back_as_logged_or_absent(tmp_path_factory, n, drift, sightings, seed):
    """With or without each optional array, and with no landmark at all (AnyValues does not store an empty array:
    the snapshot's metadata says which arrays it has)."""
    rng = np.random.default_rng(seed)
    m = _with_optional(landmark_map("robot1", n, rng), rng, drift, sightings)
    path = tmp_path_factory.mktemp("optional") / "r.rrd"
    _recording(path, [m])
    contents = read_recording(path)
    assert contents.damaged is None
    _assert_same(contents.maps["robot1"], m)


def test_a_snapshot_without_the_optional_arrays_reads_as_before(tmp_path):
    """A map that has none is logged as before session 15 (no "optional" in its metadata, the same checksum)."""
    m = landmark_map("robot1", 10, np.random.default_rng(3))
    _recording(tmp_path / "r.rrd", [m])
    read = read_recording(tmp_path / "r.rrd")
    assert read.damaged is None
    _assert_same(read.maps["robot1"], m)


def test_the_checksum_covers_the_optional_arrays(tmp_path):
    """A bit flipped in one of them (the message still decodes) leaves the snapshot out, the one before read. (The
    drift origins: uniform numbers, which LZ4 keeps as they are; a covariance's repeated off-diagonal terms are
    compressed, so its bytes cannot be found in the file.)"""
    rng = np.random.default_rng(4)
    first = _with_optional(landmark_map("robot1", 30, rng), rng)
    last = _with_optional(landmark_map("robot1", 30, rng), rng)
    path = tmp_path / "r.rrd"
    _recording(path, [first, last])
    _flip_in(path, last.drift_origins)
    read = read_recording(path)
    _assert_same(read.maps["robot1"], first)
    assert "maps/robot1" in read.damaged and "checksum" in read.damaged
