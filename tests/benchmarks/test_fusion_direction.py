"""benchmarks/fusion_direction.py counts what align(A, B) and align(B, A) decide (session 44): on the hand-built pair
of tests/fusion/test_split_merge_alignment.py, whose one direction has too few correspondences by construction, every
draw is "found one way only", the way it was built to be; the two whole copies of a map are found both ways and
consistent; a row prints the counts and the other direction's reason. With the ratio test on both sides of a match
(``--ratio-sides both``/``either``, session 45) the hand-built pair is decided the same both ways."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from benchmarks.fusion_direction import both_ways, main, print_row
from fusion.alignment_config import ROBUST
from tests.fusion.test_split_merge_alignment import TRUTH, _before, _maps


def test_a_pair_one_direction_of_which_has_too_few_correspondences_is_counted_found_one_way_only(capsys):
    flagged, other, _ = _maps(0, twins_in="other")
    rows = both_ways(other, _before(flagged), draws=2, scored=False)
    assert [(r["ab"].found, r["ba"].found) for r in rows] == [(True, False)] * 2
    assert all(r["p"] is None and r["wrong_ab"] is None for r in rows)
    kinds = print_row("twins", rows)
    assert kinds == {"one": 2}
    line = capsys.readouterr().out.strip()
    assert line.startswith("| twins | 2 | 0 | 0 | 2 | 0 | 2 (no truth) | 0 |")
    assert "only A <- B found 2×" in line and "descriptor correspondences" in line


def test_two_copies_of_one_map_are_found_both_ways_and_consistent():
    flagged, _, third = _maps(1, twins_in="other")
    before = _before(flagged)
    rows = both_ways(before, third, draws=2, scored=False)
    assert all(r["ab"].found and r["ba"].found for r in rows)
    assert all(r["p"] >= 0.01 and r["dxy"] < 0.02 for r in rows)
    assert np.allclose(rows[0]["ab"].pose, np.array([-3.0, 5.0, -1.2]), atol=0.05)
    assert not np.allclose(TRUTH, rows[0]["ab"].pose, atol=0.5)


@pytest.mark.parametrize(("sides", "found"), [("both", False), ("either", True)])
def test_with_the_ratio_test_on_both_sides_the_pair_is_decided_the_same_both_ways(sides, found):
    flagged, other, _ = _maps(0, twins_in="other")
    rows = both_ways(other, _before(flagged), draws=2, scored=False, config=replace(ROBUST, ratio_sides=sides))
    assert [(r["ab"].found, r["ba"].found) for r in rows] == [(found, found)] * 2
    assert all(r["ab"].statistics.correspondences == r["ba"].statistics.correspondences for r in rows)


def test_an_unknown_ratio_rule_is_refused(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--false-pairs", "1", "--ratio-sides", "map2"])
    assert exit_.value.code == 2 and "invalid choice: 'map2'" in capsys.readouterr().err
