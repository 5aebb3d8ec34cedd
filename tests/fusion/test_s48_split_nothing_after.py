"""A map that flagged itself but made every landmark before its gap has nothing to split (fusion/split.py).

Found on the MRCLAM recipe of docs/fastslam.md (`p3at slam dataset` for robots 1-5, then `p3at fuse` of the five):
robots 2 and 3 flag themselves after all 15 posts were mapped, so the split's part after the gap held 0 landmarks;
the map was then fused as its "part before the gap" (the whole map under another name), `p3at fuse` printed no pose
in map 0's frame and no merge weight for it. Such a map must fuse exactly as the map as given.
"""
from __future__ import annotations

import json

import numpy as np

from fusion import fuse_all
from fusion.split import check_split, fuse_checked
from runtime.cli import main


def _verdict(first_id: int) -> dict:
    return {"version": 1, "lost": True, "n_alarms": 1, "threshold": 11.5,
            "alarms": [{"t": 60.0, "since": 50.0, "statistic": 12.0, "frames": 10, "predicted": 40, "redetected": 1,
                        "expected": 15.0, "first_id_after_gap": int(first_id)}]}


def _flagged_pair(sim):
    s1, s2 = sim.building_pair(1.0, 0)
    m2 = s2.map.subset(np.arange(len(s2.map)))
    m2.ids = np.arange(len(m2))
    m2.metadata["self_check"] = _verdict(len(m2))   # every landmark made before the gap
    return s1.map, m2


def test_a_map_with_nothing_made_after_its_gap_is_used_whole(sim):
    m1, m2 = _flagged_pair(sim)
    check = check_split([m1, m2], 1, int(m2.metadata["self_check"]["alarms"][0]["first_id_after_gap"]))
    assert check.decision == "whole"
    assert "no landmark was made after the gap, so there is nothing to split: the map is used whole" in check.text
    checked = fuse_checked([m1, m2], rng=np.random.default_rng(3))
    assert checked.sources == [(0, None), (1, None)] and checked.fusion is checked.whole
    plain = fuse_all([m1, m2], rng=np.random.default_rng(3))
    np.testing.assert_array_equal(checked.fusion.map.positions, plain.map.positions)
    np.testing.assert_array_equal(checked.fusion.map.covariances, plain.map.covariances)


def test_p3at_fuse_places_a_flagged_map_with_nothing_after_its_gap(sim, tmp_path, capsys):
    s1, _ = sim.building_pair(1.0, 0)
    _, m2 = _flagged_pair(sim)
    _, s3 = sim.building_pair(1.0, 1)
    paths = []
    for k, m in enumerate([s1.map, m2, s3.map]):
        m.robot = f"robot{k + 1}"
        paths.append(str(tmp_path / f"robot{k + 1}.npz"))
        m.save(paths[-1])
    assert main(["fuse", *paths, "--out", str(tmp_path / "merged.npz"), "--json"]) in (0, 1)
    report = json.loads(capsys.readouterr().out)
    flagged = report["maps"][1]
    assert flagged["split"]["decision"] == "whole"
    assert flagged.get("pose_in_reference") is not None
