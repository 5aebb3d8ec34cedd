"""A pairwise merge group's nearest rival and its own cost check (estimation/pairwise_audit.py)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation import chi2
from estimation.constellation import pairwise_d2
from estimation.pairwise_audit import Rival, crowded, nearest_rivals, refused_alone

GATE = chi2.ppf(0.99, 2)


def rotated(points: np.ndarray, covariance: np.ndarray, angle: float, shift: np.ndarray):
    """The points and their joint covariance in a frame turned by ``angle`` and moved by ``shift``."""
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s], [s, c]])
    big = np.kron(np.eye(len(points)), r)
    return points @ r.T + shift, big @ covariance @ big.T


def layout(rival_at: float, sigma: float = 0.05):
    """A group of two names 1 cm apart (0, 1; 1 on the far side from 2), a name ``rival_at`` m from name 0 along x
    (2), a far name (3); independent, isotropic σ ``sigma`` each, so a difference has variance 2σ² per axis."""
    points = np.array([[0.0, 0.0], [-0.01, 0.0], [rival_at, 0.0], [9.0, 9.0]])
    return points, np.eye(8) * sigma ** 2


@settings(max_examples=40, deadline=None)
@given(angle=st.floats(-np.pi, np.pi), dx=st.floats(-50, 50), dy=st.floats(-50, 50),
       rival_d2=st.floats(GATE + 0.5, 40.0))
def test_the_nearest_rival_is_found_at_its_d2_in_any_frame(angle, dx, dy, rival_d2):
    sigma = 0.05
    points, covariance = layout(np.sqrt(rival_d2 * 2 * sigma ** 2), sigma)
    points, covariance = rotated(points, covariance, angle, np.array([dx, dy]))
    got = nearest_rivals(points, covariance, [(0, 1)], [0, 1, 2, 3])
    d2 = pairwise_d2(points, covariance, [0, 1, 2, 3])
    assert got[0].rival == 2 and got[0].member == 0          # name 1 is 1 cm further from it
    assert got[0].d2 == pytest.approx(d2[0, 2]) and got[0].d2 == pytest.approx(rival_d2, rel=1e-6)


def test_a_name_that_could_join_is_no_rival_unless_it_may_not_be_merged():
    points, covariance = layout(0.05)                        # d² 0.5 to both members: it could join
    assert nearest_rivals(points, covariance, [(0, 1)], [0, 1, 2, 3])[0].rival == 3
    allowed = np.ones((4, 4), bool)
    allowed[1, 2] = allowed[2, 1] = False                    # sighted in one frame with member 1: two points
    got = nearest_rivals(points, covariance, [(0, 1)], [0, 1, 2, 3], allowed=allowed)[0]
    assert got.rival == 2 and got.member == 0 and got.d2 == pytest.approx(0.5)
    assert nearest_rivals(points, covariance, [(0, 1)], [0, 1])[0] == Rival(np.inf, -1, -1)


@settings(max_examples=30, deadline=None)
@given(rival_d2=st.floats(0.5, 40.0))
def test_crowded_means_a_rival_within_the_wider_gate(rival_d2):
    sigma = 0.05
    points, covariance = layout(np.sqrt(rival_d2 * 2 * sigma ** 2), sigma)
    allowed = np.ones((4, 4), bool)
    allowed[1, 2] = allowed[2, 1] = False                    # a rival wherever it stands
    rivals = nearest_rivals(points, covariance, [(0, 1)], [0, 1, 2, 3], allowed=allowed)
    assert crowded(rivals)[0] == (rivals[0].d2 < chi2.ppf(0.999, 2))
    assert crowded(rivals, probability=0.99)[0] == (rivals[0].d2 < GATE)
    with pytest.raises(ValueError):
        crowded(rivals, probability=1.0)


def test_one_wrong_group_hides_in_a_batch_s_sum_but_not_alone():
    # session 32, robot 2 seed 1's first pairwise round: four groups, rises 0.2, 0.2, 4.3 (two absorbed) and the
    # wrong glimpse's 9.6; the batch's 14.2 is within χ²₁₀ 99 % = 23.2, the glimpse alone is not within χ²₂'s 9.21
    rises, absorbed = np.array([0.2, 0.2, 4.3, 9.6]), np.array([1, 1, 2, 1])
    assert rises.sum() <= chi2.ppf(0.99, 2 * absorbed.sum())
    assert refused_alone(rises, absorbed).tolist() == [False, False, False, True]


@settings(max_examples=60, deadline=None)
@given(rise=st.floats(-50, 60), absorbed=st.integers(1, 6))
def test_a_group_alone_is_judged_as_a_batch_of_one(rise, absorbed):
    assert refused_alone([rise], [absorbed])[0] == (rise > chi2.ppf(0.99, 2 * absorbed))
    assert refused_alone([rise], [absorbed], probability=0.999)[0] == (rise > chi2.ppf(0.999, 2 * absorbed))
    with pytest.raises(ValueError):
        refused_alone([rise], [0])
