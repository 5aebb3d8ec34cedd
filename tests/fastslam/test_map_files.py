"""The map FastSLAM produces: saved, loaded back equal, PLY, and clear errors for bad files."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.errors import MapFileError
from estimation.landmark_map import LandmarkMap


def test_best_map_saves_and_loads_back_equal(straight_run_v2, tmp_path):
    slam = straight_run_v2[0]
    original = slam.best_map(robot="robot7", metadata={"true_start_pose": [1.0, 2.0, 0.5]})
    assert len(original) > 20 and original.robot == "robot7" and original.frame == "start"
    path = tmp_path / "map.npz"
    original.save(path)
    loaded = LandmarkMap.load(path)
    for field in ("positions", "covariances", "descriptors", "ids", "counts", "seen_by", "trajectory"):
        assert np.array_equal(getattr(loaded, field), getattr(original, field)), field
    assert loaded.metadata == original.metadata and loaded.metadata["true_start_pose"] == [1.0, 2.0, 0.5]
    assert loaded.metadata["fastslam"]["n_particles"] == 10
    assert np.all(loaded.counts >= 3)  # only confirmed landmarks by default
    # covariances stay symmetric positive definite through the EKF updates
    assert np.allclose(loaded.covariances, np.swapaxes(loaded.covariances, 1, 2))
    assert np.all(np.linalg.eigvalsh(loaded.covariances) > 0)
    ply = tmp_path / "map.ply"
    original.export_ply(ply)
    lines = ply.read_text().splitlines()
    assert f"element vertex {len(original)}" in lines and len(lines) == lines.index("end_header") + 1 + len(original)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_corrupt_map_file_gives_a_clear_error(straight_run_v2, tmp_path, damage):
    path = tmp_path / "map.npz"
    straight_run_v2[0].best_map().save(path)
    data = path.read_bytes()
    path.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"\x00not a map" * 50, "empty": b""}[damage])
    with pytest.raises(MapFileError, match="map.npz"):
        LandmarkMap.load(path)
