"""Resampling and the shared copy-on-write landmark storage."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import (
    FastSLAM,
    FastSLAMConfig,
    effective_sample_size,
    low_variance_resample,
    normalise_log_weights,
)
from estimation.fastslam.store import LandmarkStore
from estimation.observations import StereoObservations


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=60).filter(lambda w: sum(w) > 1e-6),
       st.integers(0, 2**32 - 1))
def test_low_variance_copies_each_particle_floor_or_ceil_of_its_share(raw, seed):
    w = np.array(raw) / np.sum(raw)
    idx = low_variance_resample(w, np.random.default_rng(seed))
    assert idx.shape == w.shape and idx.min() >= 0 and idx.max() < len(w)
    counts = np.bincount(idx, minlength=len(w))
    share = len(w) * w
    assert np.all(counts >= np.floor(share - 1e-9)) and np.all(counts <= np.ceil(share + 1e-9))


@given(st.lists(st.floats(-50.0, 50.0), min_size=1, max_size=40))
def test_ess_bounds_and_normalisation(logs):
    w = normalise_log_weights(np.array(logs))
    assert np.isclose(w.sum(), 1.0)
    ess = effective_sample_size(w)
    assert 1.0 - 1e-9 <= ess <= len(w) + 1e-9


def test_ess_of_uniform_and_degenerate_weights():
    assert effective_sample_size(np.full(8, 1 / 8)) == 8.0
    assert effective_sample_size(np.eye(8)[3]) == 1.0


def _fill(store: LandmarkStore, particle: int, n: int, value: float) -> np.ndarray:
    g = store.append_slots(np.full(n, particle))
    store.flat_mean[g] = value
    store.flat_lid[g] = np.arange(n) + int(value) * 1000
    store.refresh_bbox(g // store.block_size)
    return g


def test_resampling_shares_blocks_and_copy_on_write_isolates_particles():
    store = LandmarkStore(3, block_size=4)
    _fill(store, 0, 6, 1.0)   # 2 blocks
    _fill(store, 1, 3, 2.0)
    store.resample(np.array([0, 0, 1]))          # particles 0 and 1 both hold particle 0's map
    assert np.array_equal(store.table[0, :2], store.table[1, :2])
    assert store.refcount[store.table[0, 0]] == 2
    blocks_before = int(np.sum(store.refcount > 0))
    store.make_writable(np.array([1]), np.array([0]))   # particle 1 writes to its first block
    assert store.table[1, 0] != store.table[0, 0] and store.table[1, 1] == store.table[0, 1]
    assert np.sum(store.refcount > 0) == blocks_before + 1
    g1 = store.table[1, 0] * 4
    store.flat_mean[g1] = 99.0
    g0 = store.particle_slots(0)
    assert np.all(store.flat_mean[g0] == 1.0)           # particle 0 did not see the write
    assert np.array_equal(store.flat_lid[store.particle_slots(1)], store.flat_lid[g0])
    # appending to a shared tail block copies it; the other holder's landmarks stay 6
    _fill(store, 0, 1, 3.0)
    assert len(store.particle_slots(0)) == 7 and len(store.particle_slots(1)) == 6
    assert len(store.particle_slots(2)) == 3


def test_filter_resampling_keeps_the_copied_particles_map_and_isolates_mutations():
    rng = np.random.default_rng(0)
    slam = FastSLAM(FastSLAMConfig(n_particles=4, version=1), np.random.default_rng(3))
    desc = rng.standard_normal((3, 64)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    cov = np.tile(np.eye(3) * 0.01, (3, 1, 1))
    points = np.array([[3.0, 0.5, 1.0], [4.0, -0.5, 1.2], [5.0, 0.2, 0.7]])
    slam.update(StereoObservations(points, cov, desc))
    # make particle 2 different: perturb its pose so its next update puts its landmarks elsewhere
    slam.poses[2] += [0.3, 0.0, 0.0]
    slam.log_weights[:] = [-50.0, -50.0, 0.0, -50.0]   # particle 2 dominates: every particle becomes it
    maps_before = slam.particle_map(2, min_count=1)
    slam.update(StereoObservations.empty())
    for m in range(4):
        after = slam.particle_map(m, min_count=1)
        assert np.array_equal(after.ids, maps_before.ids)
        assert np.allclose(after.positions, maps_before.positions)
    # now particles diverge: an observation moves particle 0's landmarks but not the others'
    slam.poses[0] += [0.05, 0.0, 0.0]
    slam.update(StereoObservations(points, cov, desc))
    moved = slam.particle_map(0, min_count=1).positions
    others = [slam.particle_map(m, min_count=1).positions for m in (1, 2, 3)]
    assert not np.allclose(moved, others[0])
    assert all(np.allclose(o, others[0]) for o in others)
