"""A map that flagged itself is split at its alarm and each part aligned (fusion/split.py).

Synthetic pairs from benchmarks/fusion_sim.py: robot 2's map ordered outwards from its start (the order a robot
makes landmarks in), its second half made "after the gap". Kicked: that half is rigidly moved, as a map that lost
its place builds the rest in a turned frame. The kicked half must never be merged where the first half's alignment
puts it; the same map without the kick, flagged all the same, must fuse exactly as without the check.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.geometry import transform_points
from estimation.landmark_map import LandmarkMap
from fusion import fuse_all, true_relative_pose
from fusion.alignment import align_at
from fusion.split import PARTS, check_split, fuse_checked, split_id, split_map

KICK = np.array([0.8, -0.6, 0.3])   # tx, ty (m), θ (rad): the frame the lost half is built in
SMALL_KICK = np.array([0.3, -0.2, 0.1])   # small enough that the kicked map still aligns whole


def _verdict(first_id: int) -> dict:
    return {"version": 1, "lost": True, "n_alarms": 1, "threshold": 11.5,
            "alarms": [{"t": 60.0, "since": 50.0, "statistic": 12.0, "frames": 10, "predicted": 40, "redetected": 1,
                        "expected": 15.0, "first_id_after_gap": int(first_id)}]}


def _pair(sim, kick=None, first_id=None, seed=0):
    """(map 1, flagged map 2, map 2 without the kick, first id after the gap)."""
    s1, s2 = sim.building_pair(1.0, seed)
    m2 = s2.map.subset(np.argsort(np.linalg.norm(s2.map.positions[:, :2], axis=1), kind="stable"))
    m2.ids = np.arange(len(m2))
    first = len(m2) // 2 if first_id is None else first_id
    true2 = m2.subset(np.arange(len(m2)))
    if kick is not None:
        m2.positions[first:] = transform_points(kick, m2.positions[first:])
    m2.metadata["self_check"] = _verdict(first)
    return s1.map, m2, true2, first


@pytest.mark.parametrize("kick", [KICK, SMALL_KICK])
def test_a_lost_half_is_placed_by_its_own_alignment_never_by_the_first_halfs(sim, kick):
    m1, m2, true2, first = _pair(sim, kick)
    checked = fuse_checked([m1, m2], rng=np.random.default_rng(0))
    (check,) = checked.checks
    assert check.agree is False and check.decision == "parts" and "disagree" in check.text
    assert [p.name for p in check.parts if p.used] == ["before", "after"]
    truth = true_relative_pose(m1, m2)
    after = checked.sources.index((1, "after"))
    placed = checked.fusion.map.positions[checked.fusion.rows[after]]
    right = transform_points(truth, true2.positions[first:])
    wrong = transform_points(check.parts[0].alignments[0].pose, m2.positions[first:])   # the first half's transform
    error, kicked = np.linalg.norm((placed - right)[:, :2], axis=1), np.linalg.norm((wrong - right)[:, :2], axis=1)
    assert np.median(error) < 0.1 and np.all(error < 0.5) and np.all(error < kicked)
    # unsplit, the map finds no alignment at all (the large kick), or its halves are merged under one transform
    # that fits neither (the small kick): robot 2's landmarks then lie farther from their place
    if checked.whole is not None:
        def off(fusion, rows):
            return np.median(np.linalg.norm((fusion.map.positions[rows] - transform_points(truth, true2.positions))
                                            [:, :2], axis=1))
        split_rows = np.concatenate([checked.fusion.rows[checked.sources.index((1, p))] for p in PARTS])
        assert off(checked.whole, checked.whole.rows[1]) > 2 * off(checked.fusion, split_rows)


def test_a_flagged_map_that_holds_is_used_whole_and_fuses_exactly_as_unchecked(sim):
    m1, m2, _, _ = _pair(sim)
    checked = fuse_checked([m1, m2], rng=np.random.default_rng(3))
    (check,) = checked.checks
    assert check.agree is True and check.decision == "whole" and "the parts agree" in check.text
    plain = fuse_all([m1, m2], rng=np.random.default_rng(3))
    assert checked.fusion is checked.whole and checked.sources == [(0, None), (1, None)]
    np.testing.assert_array_equal(checked.fusion.map.positions, plain.map.positions)
    np.testing.assert_array_equal(checked.fusion.map.covariances, plain.map.covariances)


def test_a_part_too_small_to_align_is_reported_and_left_out(sim):
    n = len(_pair(sim)[1])
    m1, m2, _, first = _pair(sim, KICK, first_id=n - 2)
    check = check_split([m1, m2], 1, first)
    assert check.parts[1].too_small and not check.parts[1].alignments
    assert check.decision == "before" and "too small to align (2 landmarks" in check.text
    checked = fuse_checked([m1, m2])
    assert checked.sources == [(0, None), (1, "before")]
    assert len(checked.fusion.map) == len(fuse_all([m1, split_map(m2, first)[0]]).map)


def test_a_part_that_shares_nothing_is_not_found_at_any_transform(sim):
    """align_at tests one given transform: maps that share nothing give no alignment there (no false 'found')."""
    first, second = sim.non_overlapping_pair(1.0, 0)
    truth = true_relative_pose(first.map, second.map)
    for pose in (truth, truth + np.array([0.3, -0.2, 0.05])):
        assert not align_at(first.map, second.map, pose).found


def test_the_split_point_is_read_from_the_verdict_and_a_malformed_one_is_named(sim):
    m1, m2, _, first = _pair(sim)
    assert split_id(m2) == first and split_id(m1) is None
    m2.metadata["self_check"] = {**_verdict(first), "lost": False}
    assert split_id(m2) is None
    for bad in ({"lost": True, "alarms": []}, {**_verdict(first), "alarms": [{"first_id_after_gap": -1}]}, [1]):
        m2.metadata["self_check"] = bad
        with pytest.raises(ValueError, match="self_check") as raised:
            split_id(m2)
        assert "\n" not in str(raised.value)
    m2.metadata["self_check"] = _verdict(first)
    merged = fuse_all([m1, m2]).map
    merged.metadata["self_check"] = _verdict(3)
    assert split_id(merged) is None   # a merged map keeps its reference map's metadata, not its own verdict


@settings(max_examples=30, deadline=None)
@given(ids=st.lists(st.integers(0, 10_000), min_size=0, max_size=40, unique=True), first=st.integers(0, 10_001))
def test_split_map_partitions_by_id(ids, first):
    n = len(ids)
    m = LandmarkMap(np.arange(3 * n, dtype=float).reshape(n, 3), np.tile(np.eye(3), (n, 1, 1)),
                    np.zeros((n, 4), np.float32), np.array(ids, np.int64))
    before, after = split_map(m, first)
    assert np.all(before.ids < first) and np.all(after.ids >= first)
    assert sorted(np.concatenate([before.ids, after.ids]).tolist()) == sorted(ids)
    np.testing.assert_array_equal(before.positions, m.positions[m.ids < first])   # each landmark keeps its row
    np.testing.assert_array_equal(after.positions, m.positions[m.ids >= first])


def test_p3at_fuse_reports_the_split_in_text_and_json(sim, tmp_path, capsys):
    from runtime.cli import main

    m1, m2, _, _ = _pair(sim, KICK)
    m1.save(tmp_path / "r1.npz")
    m2.save(tmp_path / "r2.npz")
    args = ["fuse", str(tmp_path / "r1.npz"), str(tmp_path / "r2.npz"), "--out", str(tmp_path / "m.npz")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "map 1 (robot2) flagged itself at t≈60.0 s: split at landmark id" in out and "the parts disagree" in out
    assert main(args + ["--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    split = report["maps"][1]["split"]
    assert report["maps"][0]["split"] is None and split["decision"] == "parts" and split["agree"] is False
    assert all(p["pose_in_reference"] is not None for p in split["parts"])
    assert report["merged_landmarks"] == len(LandmarkMap.load(tmp_path / "m.npz"))


def test_the_demo_summary_says_what_the_split_decided(sim):
    from runtime.fusion_report import fuse_maps
    from runtime.report import format_summary

    m1, m2, _, _ = _pair(sim, KICK)
    report = fuse_maps({"robot1": m1, "robot2": m2})
    (pair,) = report.pairs
    assert pair.split_decision == "parts" and pair.self_check.startswith("robot2 flagged itself")
    assert pair.aligned and pair.error_xy < 0.3      # the part made before the gap holds robot 2's start frame
    summary = {"robots": {}, "camera": "x", "particles": 1, "seed": 0, "duration": 1.0,
               "fusion": report.as_dict()}
    assert "robot2 -> robot1: robot2 flagged itself" in format_summary(summary)
    m1, m2, _, _ = _pair(sim)
    held = fuse_maps({"robot1": m1, "robot2": m2}).pairs[0]
    assert held.split_decision == "whole" and "the parts agree" in held.self_check
    del m2.metadata["self_check"]
    plain = fuse_maps({"robot1": m1, "robot2": m2})
    assert plain.pairs[0].self_check == "" and (plain.pairs[0].tx, plain.pairs[0].theta) == (held.tx, held.theta)
    np.testing.assert_array_equal(plain.merged.positions, fuse_maps({"robot1": m1, "robot2": m2}).merged.positions)


def test_p3at_fuse_marks_no_whole_map_alignment_used_for_a_map_merged_in_parts(sim, tmp_path, capsys):
    from runtime.cli import main

    m1, m2, _, _ = _pair(sim, SMALL_KICK)
    m1.save(tmp_path / "r1.npz")
    m2.save(tmp_path / "r2.npz")
    assert main(["fuse", str(tmp_path / "r1.npz"), str(tmp_path / "r2.npz"), "--out", str(tmp_path / "m.npz"),
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["alignments"][0]["found"] and report["maps"][1]["split"]["decision"] == "parts"
    assert [a["used"] for a in report["alignments"]] == [False]   # robot 2 was placed part by part, not whole
    m1, m2, _, _ = _pair(sim)
    m2.save(tmp_path / "r2.npz")
    assert main(["fuse", str(tmp_path / "r1.npz"), str(tmp_path / "r2.npz"), "--out", str(tmp_path / "m.npz"),
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [a["used"] for a in report["alignments"]] == [True] and report["maps"][1]["split"]["decision"] == "whole"


@settings(max_examples=50, deadline=None)
@given(pose=st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-np.pi, np.pi)),
       delta=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-0.5, 0.5)),
       sigma=st.floats(0.01, 1.0))
def test_the_parts_difference_is_symmetric_zero_for_equal_poses_and_wraps_the_angle(pose, delta, sigma):
    from fusion.alignment import Alignment
    from fusion.split import parts_difference

    cov = np.diag([sigma ** 2, sigma ** 2, (0.1 * sigma) ** 2])
    a = Alignment.from_pose(pose, cov)
    b = Alignment.from_pose(np.array(pose) + np.array(delta), cov)
    assert parts_difference(a, a)[0] < 1e-9 and parts_difference(a, a)[1] > 0.999
    ab, ba = parts_difference(a, b), parts_difference(b, a)
    assert ab[0] == pytest.approx(ba[0], rel=1e-9, abs=1e-9)
    d = np.array(delta)
    assert ab[0] == pytest.approx(d @ np.linalg.solve(2 * cov, d), rel=1e-6, abs=1e-6)
    turned = Alignment.from_pose(np.array(pose) + np.array([0.0, 0.0, 2 * np.pi]), cov)   # the same pose
    assert parts_difference(a, turned)[0] < 1e-6
