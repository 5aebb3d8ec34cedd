"""benchmarks.mrclam_constellation --hold-two-points (session 30, C): a name sighted twice in one frame holds two
posts and is flagged by the honest-names screen, which its split scores alone mostly miss; an honest map gains no
flag."""
from __future__ import annotations

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from benchmarks.mrclam_constellation import flagged_names
from tests.estimation.test_map_honesty import solved, twin_log


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2 ** 16), separation=st.floats(0.5, 1.5), direction=st.floats(-np.pi, np.pi))
def test_a_name_of_two_posts_is_flagged_with_the_hold_whatever_its_split_scores_say(seed, separation, direction):
    problem, points = twin_log(seed, separation, direction)
    assume(set(problem.pose_index[points == 0]) & set(problem.pose_index[points == 8]))   # seen together once
    solution = solved(problem)
    plain = flagged_names(problem, solution, 0.01)
    held = flagged_names(problem, solution, 0.01, two_points=True)
    assert held[0]
    assert np.array_equal(held[1:], plain[1:])        # the other names: the split-score screen's verdict only


def test_an_honest_map_gains_no_flag_from_the_hold():
    problem, _ = twin_log(4, 0.8, 1.0, one_name=False)
    solution = solved(problem)
    assert np.array_equal(flagged_names(problem, solution, 0.01, two_points=True), flagged_names(problem, solution,
                                                                                                   0.01))


def test_the_hold_without_the_screen_is_refused(capsys):
    import pytest

    from benchmarks.mrclam_constellation import main
    with pytest.raises(SystemExit):
        main(["--hold-two-points"])
    assert "--hold-two-points needs --honest-names" in capsys.readouterr().err
