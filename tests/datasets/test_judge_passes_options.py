"""benchmarks/mrclam_constellation's judge_passes with session 29's options (--fewer-rival, --distinct-points): a
later pass past a row of posts shifted by one is matched to the earlier pass without them and refused with them."""
from __future__ import annotations

import numpy as np

from .test_constellation import _row_of_posts


def test_judge_passes_refuses_a_shifted_row_with_fewer_rival_and_matches_it_without():
    from benchmarks.mrclam_constellation import Pass, judge_passes
    positions, covariance = _row_of_posts(1.35)
    covisible = np.zeros((6, 6), bool)
    covisible[:3, :3] = covisible[3:, 3:] = True          # each pass's posts were sighted together
    passes = [Pass(0.0, 20.0, np.arange(3)), Pass(20.0, 40.0, np.arange(3, 6))]
    plain = judge_passes(positions, covariance, covisible, passes, min_pairs=3, ratio=np.inf)
    assert [v.status for v in plain] == ["no_earlier", "matched"] and plain[1].pairs == [(3, 0), (4, 1), (5, 2)]
    for options in ({"fewer_rival": True}, {"fewer_rival": True, "distinct_points": True}):
        refused = judge_passes(positions, covariance, covisible, passes, min_pairs=3, ratio=np.inf, **options)
        assert [v.status for v in refused] == ["no_earlier", "ambiguous"] and refused[1].pairs == []


def test_rival_rounds_keeps_the_options_in_the_first_rounds_only():
    from types import SimpleNamespace

    from benchmarks.mrclam_constellation import rival_options
    args = SimpleNamespace(fewer_rival=True, distinct_points=False, rival_rounds=1)
    assert rival_options(args, 1) == {"fewer_rival": True, "distinct_points": False}
    assert rival_options(args, 2) == {"fewer_rival": False, "distinct_points": False}
    every = SimpleNamespace(fewer_rival=True, distinct_points=True, rival_rounds=None)
    assert rival_options(every, 9) == {"fewer_rival": True, "distinct_points": True}


def test_rival_rounds_without_a_rival_option_is_refused(capsys):
    import pytest

    from benchmarks.mrclam_constellation import main
    with pytest.raises(SystemExit):
        main(["--rival-rounds", "1"])
    assert "--rival-rounds needs --fewer-rival" in capsys.readouterr().err
