"""A map's landmarks about its rigid placement, from the drift its file keeps (fusion.shape_covariance)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from fusion import fuse_all
from fusion.shape_covariance import rigid_motions, shape_covariances, shape_levels


def _psd(rng: np.random.Generator, scale: float) -> np.ndarray:
    g = rng.normal(size=(3, 3)) * scale
    return g @ g.T


def _map(rng: np.random.Generator, n: int, drift: np.ndarray, origins: np.ndarray, local: float) -> LandmarkMap:
    x = np.column_stack([rng.uniform(-5, 5, size=(n, 2)), np.zeros(n)])
    w = x[:, :2] - origins
    H = np.zeros((n, 2, 3))
    H[:, 0, 0] = H[:, 1, 1] = 1.0
    H[:, 0, 2], H[:, 1, 2] = -w[:, 1], w[:, 0]
    P = np.tile(np.eye(3) * local, (n, 1, 1))
    P[:, :2, :2] += H @ drift @ np.swapaxes(H, 1, 2)
    return LandmarkMap(x, P, np.zeros((n, 0), np.float32), drift_covariances=drift, drift_origins=origins)


def _dense(m: LandmarkMap) -> np.ndarray:
    """The module's model written out in full: K (2N, 2N), then (I − A A⁺) K (I − A A⁺)ᵀ."""
    n = len(m)
    x, D, o = m.positions[:, :2], m.drift_covariances, m.drift_origins
    tr = np.trace(D, axis1=1, axis2=2)
    K = np.zeros((2 * n, 2 * n))

    def H(p, q):
        return np.array([[1.0, 0.0, -(p[1] - q[1])], [0.0, 1.0, p[0] - q[0]]])
    for a in range(n):
        for b in range(n):
            e = a if tr[a] <= tr[b] else b
            K[2 * a:2 * a + 2, 2 * b:2 * b + 2] = H(x[a], o[e]) @ D[e] @ H(x[b], o[e]).T
        C = H(x[a], o[a]) @ D[a] @ H(x[a], o[a]).T
        w, v = np.linalg.eigh(m.covariances[a, :2, :2] - C)
        K[2 * a:2 * a + 2, 2 * a:2 * a + 2] += v @ np.diag(np.maximum(w, 0.0)) @ v.T
    A = rigid_motions(m.positions).reshape(2 * n, 3)
    P = np.eye(2 * n) - A @ np.linalg.pinv(A)
    S = P @ K @ P.T
    return np.array([S[2 * k:2 * k + 2, 2 * k:2 * k + 2] for k in range(n)])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 12), local=st.floats(1e-4, 1e-2))
def test_a_drift_every_landmark_shares_is_rigid_and_leaves_only_the_local_part(seed, n, local):
    rng = np.random.default_rng(seed)
    drift = np.tile(_psd(rng, 0.3), (n, 1, 1))                 # one pose error, made at one place
    origins = np.tile(rng.uniform(-5, 5, size=2), (n, 1))
    m = _map(rng, n, drift, origins, local)
    shape = shape_covariances(m)
    # what is left is the local part about the rigid placement: at most the local variance, whatever the drift
    assert np.all(np.trace(shape, axis1=1, axis2=2) <= 2 * local * (1 + 1e-6))
    assert np.all(np.trace(shape, axis1=1, axis2=2) < 0.5 * np.trace(m.covariances[:, :2, :2], axis1=1, axis2=2)
                  + 2 * local)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 10))
def test_the_diagonal_blocks_equal_the_model_written_out_in_full(seed, n):
    rng = np.random.default_rng(seed)
    drift = np.array([_psd(rng, s) for s in rng.uniform(0.01, 0.5, size=n)])
    origins = rng.uniform(-5, 5, size=(n, 2))
    m = _map(rng, n, drift, origins, 1e-3)
    dense = _dense(m)
    w, v = np.linalg.eigh(dense)
    dense = v @ (np.maximum(w, 1e-8)[..., None] * np.swapaxes(v, 1, 2))
    np.testing.assert_allclose(shape_covariances(m), dense, atol=1e-9, rtol=1e-7)


def _kabsch_residuals(est: np.ndarray, true: np.ndarray) -> np.ndarray:
    """est (..., N, 2) after each draw's best rigid fit onto true (N, 2), minus true."""
    a, b = est - est.mean(axis=-2, keepdims=True), true - true.mean(axis=0)
    theta = np.arctan2(np.sum(a[..., 0] * b[:, 1] - a[..., 1] * b[:, 0], axis=-1),
                       np.sum(a[..., 0] * b[:, 0] + a[..., 1] * b[:, 1], axis=-1))
    c, s_ = np.cos(theta)[..., None], np.sin(theta)[..., None]
    turned = np.stack([c * a[..., 0] - s_ * a[..., 1], s_ * a[..., 0] + c * a[..., 1]], axis=-1)
    return turned + true.mean(axis=0) - true


def test_a_simulated_drifting_chain_scatters_about_its_rigid_fit_as_predicted():
    # a robot on a quarter circle makes one landmark per step, 2 m to its left; its pose error is a random walk
    # (δ_k = J δ_{k−1} + η_k, J carrying the heading error along the route), each landmark takes the pose error of
    # its making; the file keeps D_k and the robot's position.  Over many draws the landmarks' scatter about the
    # map's best rigid fit is what shape_covariances says, landmark by landmark (a rule that took the later
    # landmark's drift, or no cross terms, fails it)
    rng = np.random.default_rng(7)
    n, draws = 12, 4000
    phi = np.linspace(0, np.pi / 2, n)
    origins = 10 * np.column_stack([np.cos(phi), np.sin(phi)])
    true = 8 * np.column_stack([np.cos(phi), np.sin(phi)])
    Q = np.diag([1e-4, 4e-5, 2e-5])
    D = np.zeros((n, 3, 3))
    steps = []
    for k in range(1, n):
        J = np.eye(3)
        J[0, 2], J[1, 2] = -(origins[k, 1] - origins[k - 1, 1]), origins[k, 0] - origins[k - 1, 0]
        D[k] = J @ D[k - 1] @ J.T + Q
        steps.append(J)
    local = 1e-5
    H = np.zeros((n, 2, 3))
    H[:, 0, 0] = H[:, 1, 1] = 1.0
    H[:, 0, 2], H[:, 1, 2] = -(true[:, 1] - origins[:, 1]), true[:, 0] - origins[:, 0]
    P = np.tile(np.eye(3) * local, (n, 1, 1))
    P[:, :2, :2] += H @ D @ np.swapaxes(H, 1, 2)
    m = LandmarkMap(np.column_stack([true, np.zeros(n)]), P, np.zeros((n, 0), np.float32),
                    drift_covariances=D, drift_origins=origins)
    predicted = np.trace(shape_covariances(m), axis1=1, axis2=2)

    delta = np.zeros((draws, n, 3))
    for k in range(1, n):
        delta[:, k] = delta[:, k - 1] @ steps[k - 1].T + rng.multivariate_normal(np.zeros(3), Q, size=draws)
    est = true + np.einsum("nij,dnj->dni", H, delta) + rng.normal(scale=np.sqrt(local), size=(draws, n, 2))
    measured = np.mean(np.sum(_kabsch_residuals(est, true) ** 2, axis=2), axis=0)
    np.testing.assert_allclose(measured, predicted, rtol=0.12)
    assert predicted.sum() < 0.3 * np.trace(P[:, :2, :2], axis1=1, axis2=2).sum()   # most of the drift is rigid


def test_a_map_without_drift_has_no_shape_covariance():
    m = LandmarkMap(np.zeros((4, 3)), np.tile(np.eye(3), (4, 1, 1)), np.zeros((4, 0), np.float32))
    assert shape_covariances(m) is None


def _drifting_fleet(seed: int, a: float, b: float):
    """Five maps of one 40-landmark world, each landmark's file keeping a drift made somewhere on a route; each map's
    landmarks err by a draw of a I + b S_l (S_l its shape covariance): the model shape_levels fits."""
    rng = np.random.default_rng(seed)
    world = np.column_stack([rng.uniform(0, 20, 40), rng.uniform(0, 10, 40), np.zeros(40)])
    frames = [(0.0, 0.0, 0.0), (3.0, 1.0, 0.5), (-2.0, 4.0, -1.0), (5.0, -1.0, 2.0), (1.0, 6.0, 3.0)]
    maps = []
    for k, frame in enumerate(frames):
        c, s_ = np.cos(frame[2]), np.sin(frame[2])
        local = (world[:, :2] - frame[:2]) @ np.array([[c, -s_], [s_, c]])
        drift = np.array([_psd(rng, g) for g in rng.uniform(0.005, 0.05, 40) * (k + 1) / 3])
        origins = local + rng.normal(scale=2.0, size=(40, 2))
        m = _map_at(local, drift, origins)
        S = shape_covariances(m)
        noise = np.einsum("nij,nj->ni", np.linalg.cholesky(a * np.eye(2) + b * S), rng.normal(size=(40, 2)))
        m.positions[:, :2] += noise
        maps.append(m)
    return maps, frames


def _map_at(local: np.ndarray, drift: np.ndarray, origins: np.ndarray) -> LandmarkMap:
    """A map of landmarks at ``local`` whose file keeps ``drift`` made at ``origins`` (and holds its effect)."""
    n = len(local)
    w = local - origins
    H = np.zeros((n, 2, 3))
    H[:, 0, 0] = H[:, 1, 1] = 1.0
    H[:, 0, 2], H[:, 1, 2] = -w[:, 1], w[:, 0]
    P = np.tile(np.eye(3) * 1e-6, (n, 1, 1))
    P[:, :2, :2] += H @ drift @ np.swapaxes(H, 1, 2)
    return LandmarkMap(np.column_stack([local, np.zeros(n)]), P, np.zeros((n, 0), np.float32),
                       drift_covariances=drift, drift_origins=origins)


def _true_alignments(frames):
    from estimation.geometry import compose, inverse
    from fusion.alignment import Alignment
    ids = np.column_stack([np.arange(40), np.arange(40)])
    return {(i, j): Alignment.from_pose(compose(inverse(np.array(frames[i])), np.array(frames[j])), supports=ids)
            for i in range(5) for j in range(i + 1, 5)}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_levels_recover_the_floor_and_the_factor_the_maps_were_drawn_with(seed):
    a, b = 0.03 ** 2, 0.3
    maps, frames = _drifting_fleet(seed, a, b)
    fitted = shape_levels(maps, [shape_covariances(m) for m in maps], _true_alignments(frames))
    assert fitted[0] == pytest.approx(a, rel=0.35) and fitted[1] == pytest.approx(b, rel=0.35)


def test_the_drift_calibration_is_recorded_and_falls_back_without_the_drift():
    maps, frames = _drifting_fleet(0, 0.03 ** 2, 0.3)
    alignments = _true_alignments(frames)
    fused = fuse_all(maps, alignments=alignments, calibration="drift")
    assert fused.map.metadata["fusion"]["calibration"] == "drift"
    bare = [LandmarkMap(m.positions, m.covariances, m.descriptors) for m in maps]
    fallback = fuse_all(bare, alignments=alignments, calibration="drift")
    isotropic = fuse_all(bare, alignments=alignments)
    assert fallback.map.metadata["fusion"]["calibration"] == "isotropic"
    np.testing.assert_array_equal(fallback.map.positions, isotropic.map.positions)
