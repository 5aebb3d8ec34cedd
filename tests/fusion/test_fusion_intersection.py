"""Merging maps whose errors are correlated (issue 13): covariance intersection (fusion.intersection, the merge rule
"intersection") is consistent whatever the correlation between the two estimates, never claims more than the better
input, and does not halve the covariance of a map merged with itself, where the paper's Kalman update (the default
rule) does; the calibration of three or more maps gives each map's landmarks its measured scatter ("isotropic")."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from estimation.landmark_map import LandmarkMap
from fusion import Alignment, IncompatibleMapsError, fuse_all, kalman_fuse, merge
from fusion.intersection import covariance_intersection
from fusion.multi import calibrated_map, claimed_variance, covariance_scales

CHI2_2_99 = 9.210      # χ²(2) 99 % quantile

_entries = arrays(np.float64, (3, 3), elements=st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False))


def _covariance(a: np.ndarray, floor: float) -> np.ndarray:
    return a @ a.T + floor * np.eye(3)


def _gains(fuse, P1: np.ndarray, P2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """W1, W2 (3, 3) of a fusion rule that is linear in the means, x = W1 x1 + W2 x2, read through its output."""
    eye, zeros = np.eye(3), np.zeros((3, 3))
    P1s, P2s = np.repeat(P1[None], 3, 0), np.repeat(P2[None], 3, 0)
    W1 = fuse(eye, P1s, zeros, P2s)[0].T               # row k of the output is W1 e_k
    W2 = fuse(zeros, P1s, eye, P2s)[0].T
    return W1, W2


def _true_covariance(W1, W2, P1, P2, cross) -> np.ndarray:
    """Error covariance of W1 x1 + W2 x2 when the errors have covariances P1, P2 and cross-covariance ``cross``."""
    return W1 @ P1 @ W1.T + W2 @ P2 @ W2.T + W1 @ cross @ W2.T + W2 @ cross.T @ W1.T


@settings(max_examples=100, deadline=None)
@given(a1=_entries, a2=_entries, k=_entries, floor1=st.floats(1e-3, 1.0), floor2=st.floats(1e-3, 1.0),
       rho=st.floats(-1.0, 1.0))
def test_the_intersection_covers_the_true_error_whatever_the_correlation(a1, a2, k, floor1, floor2, rho):
    P1, P2 = _covariance(a1, floor1), _covariance(a2, floor2)
    # any joint covariance with these marginals: cross = L1 K L2ᵀ with ‖K‖₂ ≤ 1
    norm = np.linalg.norm(k, 2)
    K = rho * (k / norm if norm > 0 else np.eye(3))
    cross = np.linalg.cholesky(P1) @ K @ np.linalg.cholesky(P2).T
    _, P = covariance_intersection(np.zeros((1, 3)), P1[None], np.zeros((1, 3)), P2[None])
    W1, W2 = _gains(covariance_intersection, P1, P2)
    truth = _true_covariance(W1, W2, P1, P2, cross)
    scale = max(np.abs(P).max(), 1e-12)
    assert np.linalg.eigvalsh(P[0] - truth).min() >= -1e-7 * scale
    # never claims more than the better input (a plain copy of it is one of its choices)
    # (+ the 1e-12 the rule adds before inverting, once per axis)
    assert np.trace(P[0]) <= min(np.trace(P1), np.trace(P2)) * (1 + 1e-9) + 3e-12


@settings(max_examples=100, deadline=None)
@given(a=_entries, floor=st.floats(1e-4, 1.0), x=arrays(np.float64, 3, elements=st.floats(-50, 50)))
def test_an_estimate_fused_with_itself_is_unchanged(a, floor, x):
    P = _covariance(a, floor)
    xf, Pf = covariance_intersection(x[None], P[None], x[None], P[None])
    assert xf[0] == pytest.approx(x, abs=1e-6 * (1 + np.abs(x).max()))
    assert Pf[0] == pytest.approx(P, rel=1e-6, abs=1e-9 * np.abs(P).max())


@settings(max_examples=100, deadline=None)
@given(a1=_entries, a2=_entries, floor1=st.floats(1e-3, 1.0), floor2=st.floats(1e-3, 1.0),
       x1=arrays(np.float64, 3, elements=st.floats(-5, 5)), x2=arrays(np.float64, 3, elements=st.floats(-5, 5)))
# two equal near-singular inputs (κ ~ 3e4): tr P is flat in ω and its rounding once exceeded the tie tolerance, so the
# order picked ω = 0.16 or 0.84 (found by a local Hypothesis draw in session 9)
@example(a1=np.full((3, 3), 1.75180073), a2=np.full((3, 3), 1.75180073), floor1=1e-3, floor2=1e-3,
         x1=np.zeros(3), x2=np.ones(3))
def test_the_intersection_does_not_depend_on_the_order(a1, a2, floor1, floor2, x1, x2):
    P1, P2 = _covariance(a1, floor1), _covariance(a2, floor2)
    xa, Pa = covariance_intersection(x1[None], P1[None], x2[None], P2[None])
    xb, Pb = covariance_intersection(x2[None], P2[None], x1[None], P1[None])
    assert np.trace(Pa[0]) == pytest.approx(np.trace(Pb[0]), rel=1e-6)
    assert xa[0] == pytest.approx(xb[0], abs=1e-4 * (1 + np.abs(x1).max() + np.abs(x2).max()))


def test_the_kalman_update_claims_half_of_a_fully_shared_error():
    """Why the robust preset needs another rule: two estimates with one shared error are one estimate."""
    P = np.diag([0.04, 0.01, 0.0001])
    W1, W2 = _gains(kalman_fuse, P, P)
    truth = _true_covariance(W1, W2, P, P, P)       # fully correlated: x2 − x1 = 0
    _, Pk = kalman_fuse(np.zeros((1, 3)), P[None], np.zeros((1, 3)), P[None])
    assert np.linalg.eigvalsh(Pk[0] - truth).min() < -0.4 * P.min(where=P > 0, initial=1.0)
    _, Pc = covariance_intersection(np.zeros((1, 3)), P[None], np.zeros((1, 3)), P[None])
    assert Pc[0] == pytest.approx(P)


def _map(positions: np.ndarray, sigma: float, robot: str) -> LandmarkMap:
    cov = np.repeat(np.diag([sigma ** 2, sigma ** 2, 1e-6])[None], len(positions), 0)
    return LandmarkMap(positions, cov, np.zeros((len(positions), 0), np.float32), robot=robot,
                       metadata={"external_ids": list(range(len(positions)))})


def _nees_above(merged: LandmarkMap, truth: np.ndarray) -> float:
    e = merged.positions[: len(truth), :2] - truth[:, :2]
    P = merged.covariances[: len(truth), :2, :2]
    nees = np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])
    return float(np.mean(nees > CHI2_2_99))


def test_a_pair_with_correlated_errors_merges_with_an_honest_covariance():
    """Two maps of the same 400 landmarks whose errors share a common part (σ 0.10 m shared, 0.03 m each's own),
    each claiming its true σ: merged by covariance intersection the landmarks stay within their covariance; the
    paper's Kalman update (independent maps) claims σ/√2 and is confidently wrong far more often than 1 %."""
    rng = np.random.default_rng(7)
    truth = np.column_stack([rng.uniform(0, 30, (400, 2)), np.zeros(400)])
    shared = np.column_stack([rng.normal(0, 0.10, (400, 2)), np.zeros(400)])
    own = [np.column_stack([rng.normal(0, 0.03, (400, 2)), np.zeros(400)]) for _ in range(2)]
    sigma = float(np.hypot(0.10, 0.03))
    m1, m2 = _map(truth + shared + own[0], sigma, "robot1"), _map(truth + shared + own[1], sigma, "robot2")
    pairs = np.column_stack([np.arange(400), np.arange(400)])
    alignment = Alignment.from_pose(np.zeros(3), supports=pairs, preset="robust")
    honest = merge(m1, m2, alignment, 1, use_alignment_covariance=False, rule="intersection")
    assert honest.metadata["fusion"]["merge_rule"] == "intersection"
    assert len(honest) == 400
    assert _nees_above(honest, truth) < 0.03                 # χ²(2) 99 %: 1 % expected
    paper = merge(m1, m2, alignment, 1, use_alignment_covariance=False)
    assert paper.metadata["fusion"]["merge_rule"] == "kalman"
    assert _nees_above(paper, truth) > 0.1


def test_a_map_merged_with_itself_keeps_its_covariance():
    rng = np.random.default_rng(3)
    m = _map(np.column_stack([rng.uniform(0, 10, (20, 2)), np.zeros(20)]), 0.05, "robot1")
    copy = LandmarkMap(m.positions.copy(), m.covariances.copy(), m.descriptors, robot="robot2",
                       metadata=dict(m.metadata))
    pairs = np.column_stack([np.arange(20), np.arange(20)])
    merged = merge(m, copy, Alignment.from_pose(np.zeros(3), supports=pairs), 1, rule="intersection")
    assert len(merged) == 20
    assert merged.covariances == pytest.approx(m.covariances, rel=1e-5)      # the rule adds 1e-12 before inverting
    assert merged.positions == pytest.approx(m.positions, abs=1e-9)


def test_the_merge_rule_is_recorded_and_an_unknown_rule_is_refused():
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(0, 10, (12, 2)), np.zeros(12)])
    maps = [_map(pts + np.column_stack([rng.normal(0, 0.02, (12, 2)), np.zeros(12)]), 0.02, f"robot{k}")
            for k in (1, 2)]
    pairs = np.column_stack([np.arange(12), np.arange(12)])
    alignments = {(0, 1): Alignment.from_pose(np.zeros(3), supports=pairs, preset="robust")}
    fused = fuse_all(maps, "robust", alignments=alignments)
    assert fused.map.metadata["fusion"]["merge_rule"] == "kalman"        # the paper's update by default
    fused = fuse_all(maps, "robust", alignments=alignments, merge_rule="intersection")
    assert fused.map.metadata["fusion"]["merge_rule"] == "intersection"
    with pytest.raises(IncompatibleMapsError, match="unknown merge rule 'average'"):
        fuse_all(maps, "robust", alignments=alignments, merge_rule="average")
    with pytest.raises(IncompatibleMapsError, match="unknown merge rule"):
        merge(maps[0], maps[1], alignments[(0, 1)], rule="average")


def test_the_isotropic_calibration_gives_every_landmark_the_maps_measured_scatter():
    rng = np.random.default_rng(2)
    n = 9
    a = rng.normal(size=(n, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2) + 0.01 * np.eye(3)
    m = LandmarkMap(rng.normal(size=(n, 3)), cov, np.zeros((n, 0), np.float32), robot="robot1")
    iso = calibrated_map(m, 0.25, "isotropic")
    per_axis = 0.25 * claimed_variance(m)
    assert iso.covariances[:, :2, :2] == pytest.approx(np.repeat(per_axis * np.eye(2)[None], n, 0))
    assert np.all(iso.covariances[:, :2, 2] == 0) and np.all(iso.covariances[:, 2, :2] == 0)
    assert iso.covariances[:, 2, 2] == pytest.approx(0.25 * cov[:, 2, 2])
    assert calibrated_map(m, 0.25, "scaled").covariances == pytest.approx(0.25 * cov)


def test_maps_whose_claims_are_shaped_by_drift_merge_with_their_measured_scatter():
    """Five maps of 120 landmarks with independent errors (σ 0.04–0.06 m per map) that claim covariances shaped
    like a FastSLAM map's drift (smallest for the landmarks made first, 0.2–5× the map's level, unrelated to the
    error): calibrated "isotropic" (the default) each landmark gets its map's measured scatter and the merged map is
    honest; "scaled" (session 5) keeps the drift's shape and the landmarks made first are confidently wrong.
    (Seeds 0–7 of this set-up: 0–1.7 % against 16–25 % above the bound.)"""
    rng = np.random.default_rng(11)
    n = 120
    world = np.column_stack([rng.uniform(0, 30, (n, 2)), np.zeros(n)])
    shape = np.geomspace(0.2, 5.0, n)                     # claimed σ factor, growing along the route
    maps, alignments = [], {}
    for k, sigma in enumerate([0.04, 0.05, 0.05, 0.06, 0.06]):
        noisy = world + np.column_stack([rng.normal(0, sigma, (n, 2)), np.zeros(n)])
        cov = np.zeros((n, 3, 3))
        cov[:, 0, 0] = cov[:, 1, 1] = (0.3 * shape) ** 2
        cov[:, 2, 2] = 1e-6
        maps.append(LandmarkMap(noisy, cov, np.zeros((n, 0), np.float32), robot=f"robot{k + 1}",
                                metadata={"external_ids": list(range(n))}))
    pairs = np.column_stack([np.arange(n), np.arange(n)])
    for i in range(5):
        for j in range(i + 1, 5):
            alignments[(i, j)] = Alignment.from_pose(np.zeros(3), supports=pairs)

    def above(calibration: str) -> float:
        fused = fuse_all(maps, "robust", alignments=alignments, calibration=calibration)
        assert fused.covariance_scales is not None and len(fused.map) == n
        assert fused.map.metadata["fusion"]["calibration"] == calibration
        return _nees_above(fused.map, world)

    assert above("isotropic") < 0.05                    # χ²(2) 99 %: 1 % expected
    assert above("scaled") > 0.1


def test_the_calibration_bound_seldom_puts_a_map_below_its_real_scatter():
    """The three-cornered hat's σ_k² is uncertain, the most accurate map's most of all (a small difference of large
    pair variances), and an underestimate is what the merge trusts most.  Five maps of 15 landmarks with real σ
    0.03–0.15 m, 40 draws: the plain estimate is below the truth about half the time, the estimate plus one standard
    error (the default) seldom (a one-sided 84 % bound: 16 % expected)."""
    sigmas = np.array([0.03, 0.08, 0.08, 0.15, 0.15])
    n = 15
    pairs = np.column_stack([np.arange(n), np.arange(n)])
    alignments = {(i, j): Alignment.from_pose(np.zeros(3), supports=pairs) for i in range(5) for j in range(i + 1, 5)}
    below_plain, below_bound = np.zeros(5), np.zeros(5)
    draws = 40
    for seed in range(draws):
        rng = np.random.default_rng(seed)
        world = np.column_stack([rng.uniform(0, 15, (n, 2)), np.zeros(n)])
        maps = [_map(world + np.column_stack([rng.normal(0, s, (n, 2)), np.zeros(n)]), 1.0, f"robot{k + 1}")
                for k, s in enumerate(sigmas)]                       # each claims σ 1 m: the scale is the σ
        below_plain += np.sqrt(covariance_scales(maps, alignments, floor=1e-3, standard_errors=0.0)) < sigmas
        below_bound += np.sqrt(covariance_scales(maps, alignments, floor=1e-3)) < sigmas
    assert below_plain[0] / draws > 0.25
    assert np.all(below_bound / draws < 0.3)
