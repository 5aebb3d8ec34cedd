"""A found alignment that rests on its start prior says so (session 47).

A start prior removes hypotheses (fusion/prior.py), so a pair whose maps alone are ambiguous -- a building's half
turn nearly as supported as the truth -- is found with it.  Such a result stays found (the prior is the user's
stated knowledge), but the user must be able to tell it from a found the maps' own evidence carries: the
statistics say what the maps alone decide (``prior_decides``, ``without_prior_*``) and ``prior_backing`` gives the
sentence.  Rendered demo seed 19 (robot 2 first) is the case: a prior on the half turn gave "found", 19.6 m off.
"""
from __future__ import annotations

import numpy as np
from hypothesis import event, given, settings
from hypothesis import strategies as st

from estimation.geometry import compose
from fusion import align
from fusion.alignment import alignment_error_xy_theta
from fusion.prior import StartPrior
from tests.fusion.test_fusion_prior import HALF_TURN, TRUE_POSE, twin_pair

WRONG_HALF_TURN = compose(HALF_TURN, TRUE_POSE)


def _prior(mean, sigma_xy=1.0, sigma_theta=0.3):
    return StartPrior.from_sigmas(mean, sigma_xy, sigma_theta)


def test_a_right_prior_that_settles_a_half_turn_is_reported_as_resting_on_it():
    m1, m2 = twin_pair(0, common=30, twins=24)
    plain = align(m1, m2, "robust", np.random.default_rng(0))
    assert not plain.found and plain.reason.startswith("ambiguous")
    a = align(m1, m2, "robust", np.random.default_rng(0), prior=_prior(TRUE_POSE + [0.5, -0.5, 0.1]))
    assert a.found and alignment_error_xy_theta(a.pose, TRUE_POSE)[0] < 0.05
    st_ = a.statistics
    assert st_.prior_backed and st_.prior_decides == "ambiguous"
    # the maps alone: the plain alignment's own figures, not an estimate of them
    assert st_.without_prior_rival_supports == plain.statistics.second_best_supports >= 20
    assert st_.without_prior_log10_chance_probability == plain.statistics.log10_chance_probability
    assert st_.without_prior_required_supports == plain.statistics.required_supports > st_.supports
    assert st_.without_prior_rival_outside                       # the prior excluded it
    assert st_.without_prior_rival_turn > 3.0                    # the half turn
    assert st_.without_prior_rival_shift > 5.0
    text = a.prior_backing
    assert text.startswith(f"found with the prior: the maps alone are ambiguous (rival "
                           f"{st_.without_prior_rival_supports} supports against the best one's {st_.supports}, "
                           f"turned 3.1")
    assert "outside the prior" in text
    assert a.to_dict()["rests_on_prior"] == text and a.to_dict()["statistics"]["prior_backed"] is True


def test_a_wrong_prior_on_the_maps_strongest_hypothesis_is_found_and_says_it_rests_on_the_prior():
    """Demo seed 19's case: the half turn is the maps' best (twins outnumber the common landmarks) but not by enough;
    a prior centred on it makes it found, wrong by metres -- and the result says the maps alone could not decide."""
    m1, m2 = twin_pair(0, common=24, twins=30)
    assert align(m1, m2, "robust", np.random.default_rng(0)).reason.startswith("ambiguous")
    a = align(m1, m2, "robust", np.random.default_rng(0), prior=_prior(WRONG_HALF_TURN, 0.3, 0.1))
    assert a.found
    assert alignment_error_xy_theta(a.pose, TRUE_POSE)[0] > 1.0         # wrong
    assert a.statistics.prior_backed and a.prior_backing.startswith("found with the prior: the maps alone are "
                                                                     "ambiguous")


def test_an_unambiguous_pair_with_a_consistent_prior_is_not_reported_as_resting_on_it():
    m1, m2 = twin_pair(3, common=40, twins=0)
    plain = align(m1, m2, "robust", np.random.default_rng(3))
    a = align(m1, m2, "robust", np.random.default_rng(3), prior=_prior(TRUE_POSE + [0.3, 0.2, -0.05]))
    assert plain.found and a.found and np.array_equal(a.pose, plain.pose)
    assert not a.statistics.prior_backed and a.statistics.prior_decides == "" and a.prior_backing == ""
    assert a.statistics.without_prior_log10_chance_probability == plain.statistics.log10_chance_probability
    assert a.to_dict()["rests_on_prior"] is None and a.to_dict()["statistics"]["prior_backed"] is False


def test_without_a_prior_nothing_is_measured_twice():
    m1, m2 = twin_pair(4, common=40, twins=10)
    a = align(m1, m2, "robust", np.random.default_rng(4))
    assert a.found and not a.statistics.prior_backed and a.prior_backing == ""
    assert np.isnan(a.statistics.without_prior_log10_chance_probability)
    assert a.statistics.without_prior_hypotheses == 0


def test_the_flag_survives_the_inverse_and_a_not_found_carries_none():
    m1, m2 = twin_pair(0, common=30, twins=24)
    a = align(m1, m2, "robust", np.random.default_rng(0), prior=_prior(TRUE_POSE))
    assert a.found and a.inverse().prior_backing == a.prior_backing != ""
    refused = align(m1, m2, "robust", np.random.default_rng(0), prior=_prior(WRONG_HALF_TURN))
    assert not refused.found and refused.prior_backing == "" and not refused.statistics.prior_backed


@settings(max_examples=30)
@given(seed=st.integers(0, 10_000), common=st.integers(15, 35), twins=st.integers(0, 40),
       x=st.floats(-5.0, 5.0), y=st.floats(-5.0, 5.0), theta=st.floats(-np.pi, np.pi),
       off=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-0.3, 0.3)),
       on_half_turn=st.booleans())
def test_prior_backed_exactly_when_the_maps_alone_do_not_find_it(seed, common, twins, x, y, theta, off,
                                                                  on_half_turn):
    """For pairs with any number of half-turned look-alikes (none: unambiguous), any pose, with a prior within 1σ of
    the truth or of the half turn: a found alignment with the prior rests on it iff the same alignment without the
    prior is not found, and the figures it reports for the maps alone are that alignment's (the winner and the
    decoys are the same)."""
    truth = np.array([x, y, theta])
    m1, m2 = twin_pair(seed, common=common, twins=twins, pose=truth)
    centre = compose(HALF_TURN, truth) if on_half_turn else truth
    plain = align(m1, m2, "robust", np.random.default_rng(seed))
    a = align(m1, m2, "robust", np.random.default_rng(seed), prior=_prior(centre + np.array(off)))
    event(f"with the prior {'found' if a.found else 'not found'}, without {'found' if plain.found else 'not found'}")
    if not a.found:
        assert not a.statistics.prior_backed and a.prior_backing == ""
        return
    assert a.statistics.prior_backed == (not plain.found)
    assert a.statistics.without_prior_log10_chance_probability == plain.statistics.log10_chance_probability
    assert a.statistics.without_prior_rival_supports == plain.statistics.second_best_supports
    assert a.statistics.without_prior_required_supports == plain.statistics.required_supports
    if plain.found:
        assert np.array_equal(a.pose, plain.pose) and a.prior_backing == ""
    else:
        assert a.prior_backing.startswith("found with the prior: the maps alone are ")


def test_the_other_reasons_are_worded_too():
    """A prior can also decide by its smaller Bonferroni factor alone (too weak without it) or against a map's repeat
    of itself; no small pair found here reaches either, so the sentences are checked on the statistics."""
    from dataclasses import replace

    from fusion.alignment import Alignment, AlignmentStatistics

    base = AlignmentStatistics(supports=9, log10_chance_probability=-6.4, prior_hypotheses=12, self_repeat_supports=7,
                               without_prior_log10_chance_probability=-5.1, without_prior_hypotheses=250,
                               without_prior_required_supports=10)
    found = Alignment(True, "robust", np.zeros(3), None, np.zeros((0, 2), np.int64), base)
    assert found.prior_backing == ""
    weak = replace(found, statistics=replace(base, prior_decides="chance"))
    assert weak.prior_backing == ("found with the prior: the maps alone are too weak (9 supports are explainable by "
                                  "chance without the prior; false-alarm probability without the prior 10^-5.1 over "
                                  "250 hypotheses, 10 supports needed; with it 10^-6.4 over 12)")
    repeat = replace(found, statistics=replace(base, prior_decides="repeat"))
    assert repeat.prior_backing.startswith("found with the prior: the maps alone are ambiguous (one map repeats "
                                           "itself under a distinct transform with 7 supports; ")
    assert replace(repeat, found=False).prior_backing == ""
