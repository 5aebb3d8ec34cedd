"""How a flagged map's split (fusion/split.py) reads to a user: the live event line gives the decision in one
short clause, and the mission summary gives the whole sentence once, wrapped, not the same reason twice."""
from __future__ import annotations

import numpy as np

from runtime.fusion_report import fuse_maps
from runtime.report import format_summary, fusion_event_line
from tests.fusion.test_fusion_split import KICK, _pair, _verdict


def _summary(report) -> dict:
    return {"robots": {}, "camera": "x", "particles": 1, "seed": 0, "duration": 1.0, "fusion": report.as_dict()}


def test_a_flagged_map_left_out_is_one_short_clause_live_and_one_wrapped_sentence_in_the_summary(sim):
    first, second = sim.non_overlapping_pair(1.0, 0)   # nothing in common: neither part can align
    flagged = second.map
    flagged.ids = np.arange(len(flagged))
    flagged.metadata["self_check"] = _verdict(len(flagged) // 2)
    report = fuse_maps({"robot1": first.map, "robot2": flagged})
    (pair,) = report.pairs
    assert not pair.aligned and pair.split_decision == "none" and pair.note in pair.self_check
    line = fusion_event_line(40.0, pair)
    assert line == ("fusion at t=40s: robot2 does not overlap robot1 yet: robot2 flagged itself and was split at its "
                    "alarm: neither part aligns on its own, so it is left out")
    text = format_summary(_summary(report))
    assert "not aligned:" not in text                  # the split's sentence is the reason: printed once
    lines = text.splitlines()
    start = next(i for i, s in enumerate(lines) if s.startswith("robot2 -> robot1: robot2 flagged itself"))
    block = [lines[start]] + [s for s in lines[start + 1:] if s.startswith("    ")][:100]
    assert max(len(s) for s in block) <= 118
    assert " ".join(s.strip() for s in block) == f"robot2 -> robot1: {pair.self_check}"


def test_a_map_whose_parts_agree_keeps_the_found_line(sim):
    m1, m2, _, _ = _pair(sim)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    assert pair.aligned and pair.split_decision == "whole"
    assert fusion_event_line(5.0, pair).startswith(f"fusion at t=5s: robot2 -> robot1 ({pair.supports} supports")


def test_a_split_whose_parts_disagree_is_named_by_its_decision(sim):
    m1, m2, _, _ = _pair(sim, KICK)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    as_not_aligned = dict(pair.as_dict(), aligned=False)   # the clause a live line would give before a part aligns
    assert fusion_event_line(5.0, as_not_aligned).endswith(
        "robot2 flagged itself and was split at its alarm: the parts disagree, so each is merged under its own "
        "alignment")


def test_a_flagged_map_whose_parts_are_live_candidates_says_so(sim):
    """In a live fusion (fusion/confirmation.py) a part found once is a candidate: the line does not say that neither
    part aligns, but that neither is aligned yet."""
    from fusion.confirmation import ConfirmingCache

    m1, m2, _, _ = _pair(sim)
    cache = ConfirmingCache(min_gap=20.0)
    cache.start_round(20.0)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}, cache=cache).pairs
    assert not pair.aligned and pair.split_decision == "none" and "candidate: " in pair.self_check
    assert fusion_event_line(20.0, pair).endswith(
        "robot2 flagged itself and was split at its alarm: neither part is aligned yet (a part's alignment is a "
        "candidate, not yet confirmed), so it is left out")
