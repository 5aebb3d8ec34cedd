"""Known-ID maps that disagree about one identity beyond their covariances: the merged map holds that post once
(the fused map's landmark is kept, the disagreeing robot's is neither fused nor added) and says so in
``metadata["identity_conflicts"]`` (MRCLAM session 6: robot 4 put posts 19 and 20 1.4 m from where the other
four robots did, and the merge held 17 landmarks for 15 posts)."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.geometry import inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion import align, fuse_all, merge

FRAMES = [(0.0, 0.0, 0.0), (3.0, 1.0, 0.5), (-2.0, 4.0, -1.0)]


def _known_id_map(world: np.ndarray, frame, sigma: float, claimed: float, robot: str,
                  rng: np.random.Generator) -> LandmarkMap:
    """Every post of ``world`` seen from ``frame``, off by ``sigma`` per axis, claiming σ = ``claimed``."""
    local = transform_points(inverse(np.asarray(frame, float)), world)
    local[:, :2] += rng.standard_normal((len(world), 2)) * sigma
    cov = np.repeat(np.diag([claimed ** 2, claimed ** 2, 1e-6])[None], len(world), 0)
    return LandmarkMap(local, cov, np.zeros((len(world), 0), np.float32), robot=robot,
                       metadata={"external_ids": list(range(len(world)))})


def _three_maps(seed: int, displaced: float):
    """Three maps of 30 posts; robot3 places post 7 ``displaced`` metres off (σ 0.03 m, claiming 0.05 m)."""
    rng = np.random.default_rng(seed)
    world = np.column_stack([np.stack(np.meshgrid(np.arange(6) * 2.5, np.arange(5) * 2.0), -1).reshape(-1, 2)
                             + rng.uniform(-0.5, 0.5, (30, 2)), np.zeros(30)])
    maps = [_known_id_map(world, f, 0.03, 0.05, f"robot{k + 1}", rng) for k, f in enumerate(FRAMES)]
    maps[2].positions[7, :2] += displaced * np.array([0.6, 0.8])
    return world, maps


@pytest.mark.parametrize("seed", [0, 1])
def test_a_post_placed_far_off_by_one_robot_is_kept_once_and_the_disagreement_is_reported(seed):
    world, maps = _three_maps(seed, 1.5)
    result = fuse_all(maps, "robust", 1, np.random.default_rng(seed))
    assert result.unconnected == []
    ids = np.asarray(result.map.metadata["external_ids"])
    assert sorted(ids.tolist()) == list(range(30))                       # each post once
    conflicts = result.map.metadata["identity_conflicts"]
    assert [(c["identity"], c["robot"]) for c in conflicts] == [(7, "robot3")]
    c = conflicts[0]
    assert c["mahalanobis_d2"] > c["gate_d2"] and c["distance_m"] == pytest.approx(1.5, abs=0.3)
    row = int(np.flatnonzero(ids == 7)[0])
    assert c["kept_row"] == row and result.rows[2][7] == row
    assert bool(result.map.seen_by[row, result.map.robots.index("robot3")]) is False   # its estimate not used
    # the kept post is robot1's and robot2's (in robot1's frame), not pulled toward robot3's
    assert np.linalg.norm(result.map.positions[row, :2] - maps[0].positions[7, :2]) < 0.15


def test_maps_that_agree_report_no_conflict():
    _, maps = _three_maps(0, 0.0)
    result = fuse_all(maps, "robust", 1, np.random.default_rng(0))
    assert "identity_conflicts" not in result.map.metadata
    assert sorted(np.asarray(result.map.metadata["external_ids"]).tolist()) == list(range(30))


def test_two_maps_merged_pairwise_keep_a_disputed_post_once():
    _, maps = _three_maps(2, 1.5)
    alignment = align(maps[0], maps[2], "robust", np.random.default_rng(0))
    assert alignment.found and 7 not in alignment.supports[:, 1]          # the gate left the displaced post out
    merged = merge(maps[0], maps[2], alignment)
    assert sorted(np.asarray(merged.metadata["external_ids"]).tolist()) == list(range(30))
    assert [(c["identity"], c["robot"]) for c in merged.metadata["identity_conflicts"]] == [(7, "robot3")]
    np.testing.assert_allclose(merged.positions[7], maps[0].positions[7])  # robot1's post, not pulled
