"""The decision to report an alignment rests on its own evidence: chance supports, repeated structure, spread."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from fusion import IncompatibleMapsError, align, alignment_error, merge, true_relative_pose
from fusion.ransac import identity_pairs

POSE = (4.0, 2.0, 1.2)


@pytest.mark.parametrize("seed", range(6))
def test_two_15_landmark_maps_sharing_8_align(sim, seed):
    # known-ID maps (barcodes): 8 shared landmarks in a random layout, 7 of each map's own
    map1, map2, _ = sim.landmark_pair(8, 7, 7, POSE, seed=seed, sigma=0.1, descriptors="id")
    a = align(map1, map2, "robust", np.random.default_rng(seed))
    assert a.found, a.reason
    e = a.pose - np.array(POSE)                   # within the alignment's own covariance (χ²₃ 99.9 %)
    assert e @ np.linalg.solve(a.covariance, e) < 16.3, (e, a.covariance)
    assert np.hypot(e[0], e[1]) < 0.4 and abs(e[2]) < 0.05
    assert a.statistics.required_supports <= 8 and a.statistics.log10_chance_probability < -6


@pytest.mark.parametrize("seed", range(4))
def test_overconfident_covariances_do_not_throw_correct_supports_away(sim, seed):
    # landmarks 0.1 m off, covariances claiming 5 mm (FastSLAM's per-particle ones on MRCLAM): the gate's
    # floor and its scale from the supports' own residuals keep the true supports
    map1, map2, common = sim.landmark_pair(15, 0, 0, POSE, seed=seed, sigma=0.1, descriptors="id",
                                           claimed_sigma=0.005)
    a = align(map1, map2, "robust", np.random.default_rng(seed))
    assert a.found, a.reason
    assert len(a.supports) >= 14
    assert a.statistics.gate_inflation > 1.0
    err = alignment_error(a.pose, POSE)
    assert err[0] < 0.15 and err[1] < 0.15 and err[2] < 0.03, err


def test_without_descriptors_more_supports_are_needed_than_with_them(sim):
    with_ids = align(*sim.landmark_pair(15, 0, 0, POSE, seed=1, sigma=0.05, descriptors="id")[:2], "robust",
                     np.random.default_rng(0))
    geometry = align(*sim.landmark_pair(15, 0, 0, POSE, seed=1, sigma=0.05, descriptors="none")[:2], "robust",
                     np.random.default_rng(0))
    assert with_ids.found and geometry.found
    assert not geometry.statistics.descriptors
    assert with_ids.statistics.required_supports < geometry.statistics.required_supports <= 15
    assert alignment_error(geometry.pose, POSE).max() < 0.1


@pytest.mark.parametrize("descriptors", ["none", "door"])
@pytest.mark.parametrize("doors2", [range(2, 10), range(12, 20), range(0, 8)])
def test_a_corridor_of_identical_doors_does_not_fool_it(sim, descriptors, doors2):
    # whatever the true overlap (6 doors, none, all 8), a shift by whole doors fits as well: never "found"
    map1, map2 = sim.corridor_pair(range(0, 8), doors2, (3.0, 0.5, 0.3), seed=1, descriptors=descriptors)
    a = align(map1, map2, "robust", np.random.default_rng(0))
    assert not a.found
    if descriptors == "none":
        assert "ambiguous" in a.reason and a.statistics.second_best_supports >= a.statistics.supports - 4


def test_no_false_alignment_on_maps_that_do_not_overlap(sim):
    # a sample of the 1,000 pairs of benchmarks/eval_fusion.py: small maps without descriptors (geometry
    # alone, the hardest case), small known-ID maps with wrong identities, and large random maps
    found = []
    for seed in range(40):
        m1, m2, _ = sim.landmark_pair(0, 15, 15, POSE, seed=seed, sigma=0.05, descriptors="none")
        found.append(align(m1, m2, "robust", np.random.default_rng(seed)).found)
        m1, m2, _ = sim.landmark_pair(0, 15, 15, POSE, seed=seed, sigma=0.05, descriptors="id")
        m2.metadata["external_ids"] = [int(v) for v in np.random.default_rng(seed).permutation(15)]
        m1.metadata["external_ids"] = list(range(15))
        found.append(align(m1, m2, "robust", np.random.default_rng(seed)).found)
    for seed in range(10):
        m1, m2, _ = sim.random_pair(0, 250, 300, (3, 1, 0.4), seed=seed)
        found.append(align(m1, m2, "robust", np.random.default_rng(seed)).found)
    assert sum(found) == 0, sum(found)


def test_confidence_is_reported_and_monotone_in_the_overlap(sim):
    logs = []
    for common in (6, 10, 15):
        m1, m2, _ = sim.landmark_pair(common, 15 - common, 15 - common, POSE, seed=3, sigma=0.05, descriptors="id")
        st = align(m1, m2, "robust", np.random.default_rng(0)).statistics
        logs.append(st.log10_chance_probability)
        d = st.to_dict()
        assert d["false_alarm_probability"] == pytest.approx(10 ** st.log10_chance_probability)
        assert {"second_best_supports", "required_supports", "gate_inflation", "support_spread_minor"} <= set(d)
    assert logs[0] > logs[1] > logs[2]


def test_paper_preset_says_why_when_descriptors_are_absent(sim):
    m1, m2, _ = sim.landmark_pair(15, 0, 0, POSE, seed=0, descriptors="none")
    a = align(m1, m2, "paper", np.random.default_rng(0))
    assert not a.found
    assert "no descriptors" in a.reason and "at most 15 supports" in a.reason and "20" in a.reason
    assert "keeps its distance" not in a.reason
    # with more landmarks than min = 20, the paper's RANSAC runs on every pair, supports counted once each
    m1, m2, _ = sim.landmark_pair(25, 0, 0, POSE, seed=0, sigma=0.02, descriptors="none", extent=(25.0, 12.0))
    a = align(m1, m2, "paper", np.random.default_rng(0))
    assert not a.statistics.descriptors
    if a.found:
        assert alignment_error(a.pose, POSE).max() < 0.3
    else:
        assert "no descriptors" in a.reason


def test_identity_pairs_pair_equal_ids_and_every_duplicate():
    pairs = identity_pairs(np.array([5, 7, 9, -1, 7]), np.array([7, 5, 7, -1, 11]))
    assert {tuple(p) for p in pairs.tolist()} == {(0, 1), (1, 0), (1, 2), (4, 0), (4, 2)}


def test_known_id_maps_with_duplicates_and_outliers_align_or_decline(sim):
    rng = np.random.default_rng(0)
    for seed in range(5):
        m1, m2, _ = sim.landmark_pair(10, 5, 5, POSE, seed=seed, sigma=0.05, descriptors="id")
        for m in (m1, m2):
            m.metadata["external_ids"] = [int(v) for v in np.argmax(m.descriptors, axis=1)]
        c1, c2 = sim.corrupt_map(m1, rng), sim.corrupt_map(m2, rng)
        a = align(c1, c2, "robust", np.random.default_rng(seed))
        assert a.found, a.reason
        assert alignment_error(a.pose, POSE).max() < 0.1
        merged = merge(c1, c2, a)
        assert len(merged.metadata["external_ids"]) == len(merged)


def test_merge_refuses_covariances_that_are_not_symmetric_psd(sim):
    m1, m2, _ = sim.landmark_pair(10, 0, 0, POSE, seed=0, descriptors="id")
    a = align(m1, m2, "robust", np.random.default_rng(0))
    bad = LandmarkMap(m2.positions, m2.covariances.copy(), m2.descriptors, robot="robot2")
    bad.covariances[3] = np.diag([0.01, -0.02, 0.01])
    with pytest.raises(IncompatibleMapsError, match="row 3.*positive semi-definite"):
        merge(m1, bad, a)
    bad.covariances[3] = [[0.01, 0.005, 0], [0.0, 0.01, 0], [0, 0, 0.01]]
    with pytest.raises(IncompatibleMapsError, match="not symmetric"):
        merge(m1, bad, a)


@pytest.fixture(scope="module")
def mrclam(sim):
    if not sim.MRCLAM_DATASET2.is_dir():
        pytest.skip(f"MRCLAM dataset 2 not found at {sim.MRCLAM_DATASET2}")
    return [sim.mrclam_sighting_map(sim.MRCLAM_DATASET2, r) for r in range(1, 6)]


def test_mrclam_p3at_fuse_aligns_all_ten_pairs_within_the_goal(mrclam, tmp_path, capsys):
    import json

    from runtime.cli import main

    files = []
    for s in mrclam:
        files.append(str(tmp_path / f"{s.map.robot}.npz"))
        s.map.save(files[-1])
    assert main(["fuse", *files, "--out", str(tmp_path / "merged.npz"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    pairs = report["alignments"]
    assert len(pairs) == 10 and all(a["found"] and not a["low_confidence"] for a in pairs)
    assert np.median([a["error_xy"] for a in pairs]) <= 0.3
    assert np.median([a["error_theta"] for a in pairs]) <= 0.05
    # merging improves the map: the merged landmarks are nearer the truth than the best single robot's
    merged = LandmarkMap.load(tmp_path / "merged.npz")
    errors = [_rigid_fit_error(s.map, s.truth) for s in mrclam]
    assert np.median(_rigid_fit_error(merged, mrclam[0].truth)) < min(np.median(e) for e in errors)


def _rigid_fit_error(m: LandmarkMap, truth: dict) -> np.ndarray:
    """Per-landmark distance to the truth after the map's best rigid fit (identities from external_ids)."""
    ids = np.asarray(m.metadata["external_ids"])
    local, world = m.positions[:, :2], np.array([truth[int(i)] for i in ids])
    mu_l, mu_w = local.mean(0), world.mean(0)
    a, b = local - mu_l, world - mu_w
    theta = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    R = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    return np.linalg.norm(a @ R.T - b, axis=1)


def test_mrclam_with_injected_duplicates_and_outliers_never_misaligns(mrclam):
    rng = np.random.default_rng(1)
    for i, j in [(0, 1), (1, 3), (2, 4), (0, 4)]:
        for strip in (False, True):           # known ids (wrong ones on the outliers) / geometry alone
            m1, m2 = sim_corrupt(mrclam[i].map, rng, strip), sim_corrupt(mrclam[j].map, rng, strip)
            a = align(m1, m2, "robust", np.random.default_rng(i))
            if a.found:
                e = alignment_error(a.pose, true_relative_pose(m1, m2))
                assert e[0] < 0.3 and e[1] < 0.3 and e[2] < 0.05, (i, j, strip, e)


def sim_corrupt(m: LandmarkMap, rng, strip: bool) -> LandmarkMap:
    import fusion_sim

    c = fusion_sim.corrupt_map(m, rng, duplicates=3, outliers=3)
    if strip:
        c.metadata.pop("external_ids")
    return c
