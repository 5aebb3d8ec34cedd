"""The one-line reason a pair was not aligned (runtime/report.py, the mission summary and the live fusion line) says
what decided: a rival transform of the pair, or one map repeating itself (fusion/alignment.py's two ambiguous
reasons). It said "a distinct transform gathers 0" (or 3) where the map's own repeat had decided."""
from __future__ import annotations

import importlib

import numpy as np
import pytest

import tests.fusion.conftest  # noqa: F401  (benchmarks/ on sys.path for fusion_sim)
from runtime.fusion_report import fuse_maps
from runtime.report import not_aligned_reason
from tests.fusion.test_fusion_prior import twin_pair


@pytest.mark.parametrize("seed", [0, 1])
def test_a_map_that_repeats_itself_is_named_as_the_reason(seed):
    m1, m2 = importlib.import_module("fusion_sim").half_turn_pair(seed, repeated_in_map1=8)
    pair = fuse_maps({"robot1": m1, "robot2": m2}, rng=np.random.default_rng(seed)).pairs[0].as_dict()
    assert not pair["aligned"] and pair["note"].startswith("ambiguous: one map repeats itself")
    reason = not_aligned_reason(pair)
    assert "ambiguous: one map repeats itself under a distinct transform with 8 supports" in reason, reason
    assert "a distinct transform gathers" not in reason


def test_a_rival_transform_is_still_named_with_its_supports():
    m1, m2 = twin_pair(0, common=30, twins=24)       # the half turn's look-alikes: a rival of the pair
    pair = fuse_maps({"robot1": m1, "robot2": m2}, rng=np.random.default_rng(0)).pairs[0].as_dict()
    assert not pair["aligned"] and pair["note"].startswith("ambiguous: a distinct transform")
    reason = not_aligned_reason(pair)
    assert f"ambiguous: a distinct transform gathers {pair['second_best_supports']} supports" in reason, reason
    assert pair["second_best_supports"] > 0 and "repeats itself" not in reason
