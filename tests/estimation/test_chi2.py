"""estimation.chi2 returns bit for bit what scipy.stats.chi2 returns (so that replacing one by the other moves no
gate, no confirmation and no estimate), over degrees of freedom and probabilities, at the edges (0, 1, outside,
NaN, a bad dof) and broadcast over arrays; and importing it, or fusion, does not import scipy.stats."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2 as reference

from estimation import chi2

FUNCTIONS = ("cdf", "sf", "logsf", "ppf", "isf")
dofs = st.one_of(st.integers(1, 400), st.floats(1e-3, 1e3))
probabilities = st.one_of(st.floats(0.0, 1.0), st.sampled_from([1e-300, 1e-12, 1e-6, 0.001, 0.05, 0.5, 0.95,
                                                                0.999, 1 - 1e-12, 0.0, 1.0]))
values = st.one_of(st.floats(0.0, 1e4), st.sampled_from([0.0, 1e-300, 1e-9, 7.814727903251178, 1e300, np.inf]))


def same(ours, theirs) -> bool:
    ours, theirs = np.asarray(ours), np.asarray(theirs)
    return ours.dtype == theirs.dtype and ours.shape == theirs.shape and ours.tobytes() == theirs.tobytes()


@settings(max_examples=300, deadline=None)
@given(q=probabilities, df=dofs)
def test_ppf_and_isf_are_scipy_s_bit_for_bit(q, df):
    assert same(chi2.ppf(q, df), reference.ppf(q, df))
    assert same(chi2.isf(q, df), reference.isf(q, df))


@settings(max_examples=300, deadline=None)
@given(x=values, df=dofs)
def test_cdf_and_sf_are_scipy_s_bit_for_bit(x, df):
    assert same(chi2.cdf(x, df), reference.cdf(x, df))
    assert same(chi2.sf(x, df), reference.sf(x, df))


@settings(max_examples=300, deadline=None)
@given(x=values, df=dofs)
def test_logsf_is_scipy_s_bit_for_bit_where_scipy_s_is_finite(x, df):
    theirs = reference.logsf(x, df)
    if np.isfinite(theirs) or not 0 < x < np.inf:
        assert same(chi2.logsf(x, df), theirs)
    else:                                           # sf underflowed: ours is the tail's log, finite
        assert np.isfinite(chi2.logsf(x, df)) and chi2.logsf(x, df) < np.log(np.finfo(float).tiny)


@settings(max_examples=200, deadline=None)
@given(df=st.one_of(st.integers(1, 200), st.floats(0.5, 200.0)), x=st.floats(1.0, 1e7),
       step=st.floats(1e-3, 1e4))
def test_logsf_past_the_underflow_is_the_tail_continued_and_decreasing(df, x, step):
    """Where sf is finite but tiny, the continued fraction the underflow uses agrees with log(sf) to 1e-12; and the
    log tail falls as x grows, below where sf underflows too."""
    x = max(x, 2.0 * df + 20.0)                      # the continued fraction's range, x/2 > df/2 + 1
    with np.errstate(divide="ignore"):
        theirs = np.log(reference.sf(x, df))
    if np.isfinite(theirs) and theirs < -50:
        ours = chi2._log_upper_gamma_regularised(np.array([df / 2.0]), np.array([x / 2.0]))[0]
        assert ours == pytest.approx(theirs, rel=1e-12)
    assert chi2.logsf(x + step, df) < chi2.logsf(x, df)


def test_logsf_far_in_the_tail_is_exact_where_it_is_known():
    # χ²₂: sf = exp(−x/2) exactly; scipy's logsf is −inf from x ≈ 1490 on
    for x in (1000.0, 1500.0, 1e4, 1e8):
        assert chi2.logsf(x, 2) == pytest.approx(-x / 2, rel=1e-14)
    assert np.isneginf(reference.logsf(1e4, 2))


@pytest.mark.parametrize("name", FUNCTIONS)
@pytest.mark.parametrize("arg", [-0.5, 1.5, -np.inf, np.nan, 0.0, 1.0, np.inf])
@pytest.mark.parametrize("df", [3, 0, -1, np.nan, np.inf])
def test_the_edges_are_scipy_s(name, arg, df):
    with np.errstate(invalid="ignore"):
        assert same(getattr(chi2, name)(arg, df), getattr(reference, name)(arg, df))


@settings(max_examples=50, deadline=None)
@given(p=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8), dof=st.lists(st.integers(1, 60), min_size=1,
                                                                             max_size=8))
def test_arrays_broadcast_as_scipy_s(p, dof):
    p, dof = np.array(p)[:, None], np.array(dof)[None, :]
    for name in FUNCTIONS:
        assert same(getattr(chi2, name)(p, dof), getattr(reference, name)(p, dof))
        assert same(getattr(chi2, name)(p[:, 0], 3), getattr(reference, name)(p[:, 0], 3))


def test_the_gates_the_code_uses():
    assert chi2.ppf(0.95, 3) == pytest.approx(7.814727903251178, rel=1e-15)
    assert chi2.isf(0.05, 3) == pytest.approx(chi2.ppf(0.95, 3), rel=1e-12)
    assert chi2.sf(chi2.ppf(0.999, 3), 3) == pytest.approx(0.001, rel=1e-12)


@pytest.mark.parametrize("modules", ["estimation.chi2", "fusion", "estimation.odometry_consistency, "
                                     "estimation.frontend.evaluation, estimation.fastslam.unknown_rescue"])
def test_importing_the_code_that_uses_it_does_not_import_scipy_stats(modules):
    # scipy.stats costs ~0.5 s a process (every benchmark's --help paid it); these modules need four χ² functions
    code = f"import sys, {modules}; print('scipy.stats' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"
