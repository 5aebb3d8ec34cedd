"""The overdispersed chance law (``AlignmentConfig.chance_model="negative_binomial"``, session 51; option, default
"poisson").

The decoys' chance counts on the rendered demo's maps have variance/mean 1.4-2.2 (landmarks clustered along walls:
a decoy that lays one wall on another gathers several supports at once).  Poisson's tail with the same mean is then
too thin where a false alarm lives: the best of N wrong hypotheses reaches more supports than it allows.  Here: the
negative binomial tail (fusion.evidence.chance_tail) is Poisson's at dispersion 1 and has the right moments; the
quasi-Poisson bound of the mean (dispersed_rate) covers an overdispersed rate where Poisson's does not; the false
alarms of the maximum of N clustered counts stay at the level the NB null sets, where Poisson's exceed it many
times over; and the option through align / align_at.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import gammaincinv, pdtrc

from fusion import ROBUST, IncompatibleMapsError, align, alignment_error
from fusion.alignment import align_at
from fusion.evidence import chance_tail, dispersed_rate, log10_false_alarm

NB = replace(ROBUST, chance_model="negative_binomial")

rates = st.floats(min_value=1e-3, max_value=30.0)
dispersions = st.floats(min_value=1.0, max_value=8.0)
excesses = st.integers(min_value=1, max_value=60)


def clustered_counts(rng: np.random.Generator, size: int, hits: float = 0.12, p: float = 0.6) -> np.ndarray:
    """(size,) counts that are not negative binomial but clustered: Poisson(``hits``) clusters per decoy, each of a
    geometric number of supports (mean 1/p): mean hits/p = 0.2, variance/mean (2 - p)/p = 2.33, about what the
    rendered demo's decoys show."""
    k = rng.poisson(hits, size)
    sizes = rng.geometric(p, int(k.sum()))
    return np.bincount(np.repeat(np.arange(size), k), weights=sizes, minlength=size)


@settings(max_examples=200, deadline=None)
@given(rates, excesses)
def test_the_tail_is_poissons_at_dispersion_one(rate, k):
    assert chance_tail(k, rate, 1.0) == pdtrc(k - 1, rate)
    assert log10_false_alarm(k, rate, 50, 1.0) == log10_false_alarm(k, rate, 50)


def test_the_tail_tends_to_poissons_as_the_dispersion_tends_to_one():
    worst = 0.0
    for rate in np.geomspace(0.01, 30.0, 13):
        for k in range(1, 31):
            p = pdtrc(k - 1, rate)
            worst = max(worst, abs(chance_tail(k, rate, 1.0 + 1e-8) - p) / p)
    assert worst < 1e-2          # measured 4e-4: the NB's own limit, not a switch at some φ


@settings(max_examples=200, deadline=None)
@given(rates, dispersions, excesses)
def test_the_tail_falls_with_the_excess_and_rises_with_the_rate(rate, phi, k):
    t = chance_tail(k, rate, phi)
    assert 0.0 <= chance_tail(k + 1, rate, phi) <= t <= 1.0
    assert chance_tail(k, rate * 1.5, phi) >= t


@pytest.mark.parametrize("rate,phi", [(0.05, 1.5), (0.2, 1.8), (0.2, 4.0), (1.0, 2.5), (5.0, 6.0)])
def test_the_tail_has_the_mean_and_variance_it_claims(rate, phi):
    # E X = Σ_{k≥1} P(X ≥ k), E X² = Σ_{k≥1} (2k − 1) P(X ≥ k)
    k = np.arange(1, 2000)
    tails = np.array([chance_tail(int(j), rate, phi) for j in k])
    assert tails[-1] < 1e-14
    mean = tails.sum()
    variance = ((2 * k - 1) * tails).sum() - mean ** 2
    assert mean == pytest.approx(rate, rel=1e-6)
    assert variance == pytest.approx(phi * rate, rel=1e-6)


def test_an_overdispersed_tail_is_heavier_than_poissons_above_the_mean():
    for rate, phi in [(0.2, 1.8), (0.2, 1.4), (3.0, 2.0)]:
        for k in range(int(rate) + 2, 40):
            assert chance_tail(k, rate, phi) > pdtrc(k - 1, rate)


def test_dispersed_rate_is_poissons_bound_for_poisson_counts_without_spread():
    counts = np.array([0.0, 1.0] * 500)            # variance/mean 1.0 (ddof 1: 1.001, so φ just above 1)
    bound, phi = dispersed_rate(np.zeros(1000) + 0.0)
    assert (bound, phi) == (pytest.approx(gammaincinv(1.0, 0.95) / 1000), 1.0)   # no support seen: not a zero rate
    bound, phi = dispersed_rate(counts)
    assert phi == pytest.approx(1.0, abs=0.01)
    assert bound == pytest.approx(gammaincinv(counts.sum() + 1.0, 0.95) / 1000, rel=0.01)
    under = np.ones(1000)                           # variance 0: never claimed below Poisson's
    assert dispersed_rate(under) == (pytest.approx(gammaincinv(1001.0, 0.95) / 1000), 1.0)


def test_the_dispersed_bound_covers_a_clustered_rate_where_poissons_does_not():
    """1,000 draws of 1,000 decoys' clustered counts (true mean 0.2, φ 2.33).  An honest 95 % bound covers the mean on
    Binomial(1000, 0.95) of them, sd 6.9 (0.0069): 0.93 is 3 sd below.  Poisson's bound (today's) covered 0.864 at
    this seed, 13 sd below 0.95; asserted below 0.90 (7 sd)."""
    rng = np.random.default_rng(51)
    poisson = nb = 0
    for _ in range(1000):
        c = clustered_counts(rng, 1000)
        poisson += gammaincinv(c.sum() + 1.0, 0.95) / 1000 >= 0.2
        nb += dispersed_rate(c)[0] >= 0.2
    assert nb / 1000 >= 0.93
    assert poisson / 1000 <= 0.90


def test_the_best_of_n_clustered_counts_stays_within_the_nb_level_and_not_poissons():
    """What a false alarm is: the best of N = 100 wrong hypotheses reaching the supports the null asks for at level
    0.05 (N · P(X ≥ k) ≤ 0.05, the rate and φ measured on 1,000 decoys of the same law).  Over 4,000 blocks a level
    0.05 test exceeds it Binomial(4000, ≤ 0.05), sd ≤ 0.0034: asserted ≤ 0.06 (3 sd above; Bonferroni is conservative,
    measured 0.018).  Poisson's threshold (4 supports beyond the two, where the NB's asks 6-14, mostly 8-10) was
    reached in 0.60 of the blocks at this seed; asserted ≥ 0.30."""
    rng = np.random.default_rng(5151)
    level = np.log10(0.05)
    blocks, poisson, nb = 4000, 0, 0
    for _ in range(blocks):
        c = clustered_counts(rng, 1000)
        rate_p = gammaincinv(c.sum() + 1.0, 0.95) / 1000
        rate_n, phi = dispersed_rate(c)
        k_p = next(k for k in range(1, 500) if log10_false_alarm(k, rate_p, 100) <= level)
        k_n = next(k for k in range(1, 500) if log10_false_alarm(k, rate_n, 100, phi) <= level)
        best = clustered_counts(rng, 100).max()
        poisson += best >= k_p
        nb += best >= k_n
    assert nb / blocks <= 0.06
    assert poisson / blocks >= 0.30


def test_the_option_through_align_finds_a_true_overlap_and_asks_no_fewer_supports(sim):
    truth = np.array([6.0, -3.0, 0.7])
    m1, m2, _ = sim.random_pair(60, 140, 160, truth, seed=3)
    a_p = align(m1, m2, "robust", np.random.default_rng(0))
    a_n = align(m1, m2, NB, np.random.default_rng(0))
    assert a_p.found and a_n.found
    assert max(alignment_error(a_n.pose, truth)[:2]) < 0.1
    assert a_n.statistics.required_supports >= a_p.statistics.required_supports
    assert a_n.statistics.log10_chance_probability >= a_p.statistics.log10_chance_probability


def test_the_option_finds_nothing_on_maps_that_share_nothing(sim):
    for name, make in sim.false_pair_kinds().items():
        for seed in range(2):
            m1, m2 = make(seed)
            m1, m2 = getattr(m1, "map", m1), getattr(m2, "map", m2)
            assert not align(m1, m2, NB, np.random.default_rng(seed)).found, (name, seed)


def test_align_at_takes_the_option(sim):
    truth = np.array([6.0, -3.0, 0.7])
    m1, m2, _ = sim.random_pair(60, 140, 160, truth, seed=3)
    at_p = align_at(m1, m2, truth, "robust", np.random.default_rng(1))
    at_n = align_at(m1, m2, truth, NB, np.random.default_rng(1))
    assert at_p.found and at_n.found
    assert at_n.statistics.expected_chance_supports >= at_p.statistics.expected_chance_supports


def test_an_unknown_chance_model_is_refused(sim):
    truth = np.array([1.0, 0.0, 0.2])
    m1, m2, _ = sim.random_pair(30, 40, 40, truth, seed=1)
    bad = replace(ROBUST, chance_model="gauss")
    with pytest.raises(IncompatibleMapsError, match=r"^unknown chance_model 'gauss' \(choose from poisson, "
                                                    r"negative_binomial\)$"):
        align(m1, m2, bad, np.random.default_rng(0))
    with pytest.raises(IncompatibleMapsError, match="unknown chance_model 'gauss'"):
        align_at(m1, m2, truth, bad, np.random.default_rng(0))
    assert ROBUST.chance_model == "poisson"


def test_maps_whose_chance_counts_are_poisson_decide_as_the_default(sim):
    """Two 15-landmark maps with identities, overlapping whole (MRCLAM-like): chance counts without the winner's
    supports are Poisson (φ 1), so the option decides as the default, figure for figure.  The decoys that land near
    the winner, a little turned, gather part of its supports; counted, they gave φ 1.5-9 on MRCLAM's maps (a first
    version that left out only the decoys within two gate radii of the winner asked 10-20 supports there where 6-8
    are needed, 3 of 10 pairs lost)."""
    for seed in range(4):
        m1, m2, _ = sim.landmark_pair(15, 0, 0, (3.0, -1.0, 0.8), seed=seed)
        a_p = align(m1, m2, "robust", np.random.default_rng(seed))
        a_n = align(m1, m2, NB, np.random.default_rng(seed))
        assert a_p.found and a_n.found
        assert a_n.statistics.required_supports == a_p.statistics.required_supports
        assert a_n.statistics.log10_chance_probability == a_p.statistics.log10_chance_probability
