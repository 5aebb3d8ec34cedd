"""benchmarks/fusion_decisions.py compare: a moved decision is reported, round-off of a pose within 1e-9 is not."""
from __future__ import annotations

import copy

import fusion_decisions  # benchmarks/, on the path by tests/fusion/conftest.py
import pytest


def _record(**changes) -> dict:
    record = {"k": "align", "found": True, "reason": "", "pose": [float.hex(12.0), float.hex(-3.0), float.hex(2.2)],
              "cov": None, "start": None, "supports": [[0, 1], [2, 3]],
              "stats": {"supports": 2, "log10_chance_probability": float.hex(-7.5), "residual_rms": None,
                        "second_best_turn": float.hex(float("nan"))}}
    record.update(changes)
    return record


def test_the_same_decisions_give_no_difference():
    old = [_record(), {"k": "decoy", "v": float.hex(0.25)}]
    assert fusion_decisions.differences(old, copy.deepcopy(old)) == []


@pytest.mark.parametrize(("change", "field"), [
    ({"found": False}, "found"),
    ({"supports": [[0, 1]]}, "supports"),
    ({"pose": [float.hex(12.0 + 1e-6), float.hex(-3.0), float.hex(2.2)]}, "pose"),
])
def test_a_moved_decision_is_reported(change, field):
    found = fusion_decisions.differences([_record()], [_record(**change)])
    assert len(found) == 1 and field in found[0]


def test_round_off_within_the_tolerance_is_not_a_difference():
    nudged = _record(pose=[float.hex(12.0 * (1 + 1e-13)), float.hex(-3.0), float.hex(2.2)])
    assert fusion_decisions.differences([_record()], [nudged]) == []
    stats = dict(_record()["stats"], log10_chance_probability=float.hex(-7.0))
    assert "log10_chance_probability" in fusion_decisions.differences([_record()], [_record(stats=stats)])[0]


def test_a_changed_decoy_rate_or_a_missing_record_is_reported():
    old = [_record(), {"k": "decoy", "v": float.hex(0.25)}]
    assert len(fusion_decisions.differences(old, [_record(), {"k": "decoy", "v": float.hex(0.26)}])) == 1
    assert "2 records against 1" in fusion_decisions.differences(old, old[:1])[0]
