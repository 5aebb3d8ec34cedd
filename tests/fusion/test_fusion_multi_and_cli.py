"""More than two robots, and the ``p3at fuse`` command end to end."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.geometry import between, compose, inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion import NoOverlapError, alignment_error, fuse_all
from runtime.cli import main


def _three_robot_maps(seed: int = 0):
    """Three robots in a row along a 40 m strip: 1 overlaps 2, 2 overlaps 3, 1 and 3 share nothing."""
    rng = np.random.default_rng(seed)
    n = 600
    pts = np.column_stack([rng.uniform(0, 40, n), rng.uniform(0, 8, n), rng.uniform(0, 2.5, n)])
    desc = rng.standard_normal((n, 64))
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    starts = [np.array([2.0, 4.0, 0.0]), np.array([15.0, 3.0, 2.0]), np.array([30.0, 5.0, -1.0])]
    spans = [(0, 18), (12, 30), (24, 40)]
    maps = []
    for k, (start, (lo, hi)) in enumerate(zip(starts, spans, strict=True)):
        rows = np.flatnonzero((pts[:, 0] >= lo) & (pts[:, 0] < hi))
        local = transform_points(inverse(start), pts[rows]) + rng.normal(scale=0.03, size=(len(rows), 3))
        d = desc[rows] + rng.normal(scale=0.2 / 8, size=(len(rows), 64))
        maps.append(LandmarkMap(local, np.repeat(np.eye(3)[None] * 0.03 ** 2, len(rows), 0),
                                d / np.linalg.norm(d, axis=1, keepdims=True), robot=f"robot{k + 1}",
                                metadata={"true_start_pose": start.tolist()}))
    return maps, starts, pts


def test_three_maps_fuse_through_the_strongest_alignments():
    maps, starts, _ = _three_robot_maps()
    result = fuse_all(maps, "robust", 1, np.random.default_rng(0))
    assert not result.alignments[(0, 2)].found            # 1 and 3 share nothing...
    assert sorted(result.tree) == [(0, 1), (1, 2)]         # ...so 3 joins through 2
    for k in range(3):
        assert alignment_error(result.poses[k], between(starts[0], starts[k])) == pytest.approx(np.zeros(3), abs=0.03)
    # uncertainty accumulates along the chain: θ of map 3 = θ of map 2 + θ of the 2-3 alignment
    assert result.covariances[2][2, 2] == pytest.approx(
        result.covariances[1][2, 2] + result.alignments[(1, 2)].covariance[2, 2])
    fused = result.map
    assert fused.robots == ["robot1", "robot2", "robot3"]
    assert len(fused) < sum(len(m) for m in maps)
    assert fused.seen_by[:, [0, 1]].all(axis=1).sum() > 20 and fused.seen_by[:, [1, 2]].all(axis=1).sum() > 20
    # every landmark of every map went somewhere, at its true place
    for k, m in enumerate(maps):
        x = transform_points(result.poses[k], m.positions)
        assert np.linalg.norm(fused.positions[result.rows[k]] - x, axis=1).max() < 0.3


def test_a_map_that_overlaps_nothing_is_left_out():
    maps, _, _ = _three_robot_maps()
    result = fuse_all([maps[0], maps[2], maps[1]], "robust", 2, np.random.default_rng(1))
    assert result.unconnected == [] and len(result.tree) == 2
    with pytest.raises(NoOverlapError):
        fuse_all([maps[0], maps[2]], "robust", 1, np.random.default_rng(1))
    # a fourth map far away joins nothing: left out, the rest still fused
    far = LandmarkMap(maps[2].positions + [100.0, 0.0, 0.0], maps[2].covariances,
                      np.roll(maps[2].descriptors, 7, axis=1), robot="robot4")
    partial = fuse_all([maps[0], maps[1], far], "robust", 1, np.random.default_rng(1))
    assert partial.unconnected == [2] and partial.poses[2] is None and partial.rows[2] is None
    assert len(partial.map) < len(maps[0]) + len(maps[1])


@pytest.fixture(scope="module")
def map_files(tmp_path_factory, sim):
    d = tmp_path_factory.mktemp("maps")
    s1, s2 = sim.building_pair(1.0, seed=5)
    n1, n2 = sim.non_overlapping_pair(1.0, seed=5)
    s1.map.save(d / "r1.npz")
    s2.map.save(d / "r2.npz")
    n2.map.save(d / "apart.npz")
    (d / "bad.npz").write_bytes(b"not a map")
    return d


def test_cli_fuses_two_maps_and_prints_the_error_against_truth(map_files, capsys):
    out = map_files / "merged.npz"
    assert main(["fuse", str(map_files / "r1.npz"), str(map_files / "r2.npz"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "supports" in text and "error vs true start poses" in text and "merged map" in text
    merged = LandmarkMap.load(out)
    assert merged.robots == ["robot1", "robot2"]
    assert main(["fuse", str(map_files / "r1.npz"), str(map_files / "r2.npz"), "--out", str(out), "--json",
                 "--preset", "paper", "--method", "2"]) == 0
    report = json.loads(capsys.readouterr().out)
    a = report["alignments"][0]
    assert a["found"] and a["preset"] == "paper" and max(a["error"]) < 0.2
    assert report["merged_landmarks"] == len(LandmarkMap.load(out))
    assert report["maps"][0]["landmarks"] + report["maps"][1]["landmarks"] - report["common_landmarks"] \
        == report["merged_landmarks"]


def test_cli_reports_maps_that_do_not_overlap(map_files, capsys):
    out = map_files / "none.npz"
    assert main(["fuse", str(map_files / "r1.npz"), str(map_files / "apart.npz"), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert "no overlap" in captured.out and "do not overlap" not in captured.out
    assert "overlaps the reference" in captured.err
    assert not out.exists()


def test_cli_rejects_a_malformed_map_file(map_files, capsys):
    code = main(["fuse", str(map_files / "r1.npz"), str(map_files / "bad.npz"), "--out", str(map_files / "x.npz")])
    assert code == 2
    assert "bad.npz" in capsys.readouterr().err
    assert main(["fuse", str(map_files / "r1.npz"), str(map_files / "missing.npz"), "--out",
                 str(map_files / "x.npz")]) == 2
    assert "missing.npz" in capsys.readouterr().err


def test_compose_helpers_agree_with_tree_poses():
    maps, starts, _ = _three_robot_maps()
    result = fuse_all(maps, "robust", 1, np.random.default_rng(0))
    chained = compose(result.alignments[(0, 1)].pose, result.alignments[(1, 2)].pose)
    assert result.poses[2] == pytest.approx(chained)


def test_cli_reports_the_confidence_and_the_demo_error_columns(map_files, capsys):
    out = map_files / "merged_c.npz"
    assert main(["fuse", str(map_files / "r1.npz"), str(map_files / "r2.npz"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "false-alarm probability" in text and "needed on these maps" in text and "precision (1σ)" in text
    assert "error xy" in text and "error θ" in text and "|Δtx|" not in text
    assert main(["fuse", str(map_files / "r1.npz"), str(map_files / "r2.npz"), "--out", str(out), "--json"]) == 0
    a = json.loads(capsys.readouterr().out)["alignments"][0]
    assert a["false_alarm_probability"] < 1e-6 and not a["low_confidence"]
    assert a["error_xy"] == pytest.approx(np.hypot(a["error"][0], a["error"][1]))
    assert a["error_theta"] == pytest.approx(a["error"][2])
    assert a["statistics"]["required_supports"] <= a["supports_count"]


def test_cli_warns_when_the_paper_preset_accepts_weak_evidence(sim, tmp_path, capsys):
    # a corridor of identical doors without descriptors: the paper's rule (20 supports) accepts a shift by
    # whole doors, the evidence says any shift fits as well; the robust preset declines
    m1, m2 = sim.corridor_pair(range(0, 8), range(2, 10), (3.0, 0.5, 0.3), seed=1, descriptors="none")
    m1.save(tmp_path / "c1.npz")
    m2.save(tmp_path / "c2.npz")
    files = [str(tmp_path / "c1.npz"), str(tmp_path / "c2.npz"), "--out", str(tmp_path / "m.npz")]
    code = main(["fuse", *files, "--preset", "paper", "--json"])
    captured = capsys.readouterr()
    a = json.loads(captured.out)["alignments"][0]
    assert code == 0 and a["found"] and a["low_confidence"]
    assert "low confidence" in captured.err
    assert main(["fuse", *files]) == 1
    assert "ambiguous" in capsys.readouterr().out


def test_pair_result_carries_the_confidence(sim):
    from runtime.fusion_report import fuse_maps

    s1, s2 = sim.building_pair(1.0, seed=3)
    report = fuse_maps({"robot1": s1.map, "robot2": s2.map}, rng=np.random.default_rng(0))
    p = report.pairs[0]
    assert p.aligned and 0 < p.false_alarm_probability < 1e-6 and not p.low_confidence
    assert p.required_supports <= p.supports
    assert 0 < p.sigma_xy < 0.05 and 0 < p.sigma_theta < 0.01
    d = report.as_dict()["pairs"][0]
    assert {"false_alarm_probability", "required_supports", "second_best_supports", "low_confidence",
            "error_xy", "error_theta"} <= set(d)
    n1, n2 = sim.non_overlapping_pair(1.0, seed=3)
    none = fuse_maps({"robot1": n1.map, "robot2": n2.map}, rng=np.random.default_rng(0)).pairs[0]
    assert not none.aligned and none.note and not none.low_confidence
