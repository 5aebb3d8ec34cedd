"""The closed-form symmetric 3×3 algebra of estimation.fastslam.linalg against numpy's dense algebra."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam.linalg import (
    full_sym_product,
    joseph_update,
    sym_adjugate,
    sym_components,
    sym_inverse,
    sym_matrices,
    sym_matvec,
    sym_product,
    sym_quadratic,
    sym_rotate_z,
)


def _spd(rng, n):
    a = rng.standard_normal((n, 3, 3))
    return a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(3)


def _rows(full):
    """(n, 3, 3) -> nested [i][j] rows of (n,) arrays, the gain format of linalg."""
    return [[full[:, i, j] for j in range(3)] for i in range(3)]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 9), theta=st.floats(-7.0, 7.0))
def test_closed_forms_match_dense_algebra(seed, n, theta):
    rng = np.random.default_rng(seed)
    s, r = _spd(rng, n), _spd(rng, n)
    k = rng.standard_normal((n, 3, 3))
    v = rng.standard_normal((n, 3))
    s6, r6 = sym_components(s), sym_components(r)
    np.testing.assert_allclose(sym_matrices(s6), s)
    np.testing.assert_allclose(sym_matrices(sym_inverse(s6)), np.linalg.inv(s), rtol=1e-6, atol=1e-9)
    adj, det = sym_adjugate(s6)
    np.testing.assert_allclose(det, np.linalg.det(s), rtol=1e-9)
    np.testing.assert_allclose(sym_matvec(s6, v.T).T, (s @ v[..., None])[..., 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sym_quadratic(s6, v.T), np.einsum("pi,pij,pj->p", v, s, v), rtol=1e-10)
    np.testing.assert_allclose(np.array(sym_product(s6, r6)).transpose(2, 0, 1), s @ r, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(np.array(full_sym_product(_rows(k), s6)).transpose(2, 0, 1), k @ s, rtol=1e-10,
                               atol=1e-10)
    eye = np.eye(3)
    joseph = (eye - k) @ s @ np.swapaxes(eye - k, 1, 2) + k @ r @ np.swapaxes(k, 1, 2)
    np.testing.assert_allclose(sym_matrices(joseph_update(s6, _rows(k), r6)), joseph, rtol=1e-9, atol=1e-9)
    c, sn = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(sym_matrices(sym_rotate_z(np.full(n, c), np.full(n, sn), s6)), rot @ s @ rot.T,
                               rtol=1e-10, atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 9))
def test_closed_form_cholesky_matches_lapack_and_flags_indefinite_matrices(seed, n):
    from estimation.fastslam.linalg import lower_matvec, sym_cholesky
    rng = np.random.default_rng(seed)
    s = _spd(rng, n)
    l6, ok = sym_cholesky(sym_components(s))
    assert ok.all()
    lower = np.linalg.cholesky(s)
    v = rng.standard_normal((3, n))
    np.testing.assert_allclose(lower_matvec(l6, v), np.einsum("nij,jn->in", lower, v), rtol=1e-9, atol=1e-12)
    indefinite = s - 2.0 * np.linalg.eigvalsh(s)[:, -1:, None] * np.eye(3)   # shift below zero
    assert not sym_cholesky(sym_components(indefinite))[1].any()
