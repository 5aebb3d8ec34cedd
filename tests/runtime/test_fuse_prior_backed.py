"""A found alignment that rests on its start prior says so in every report: ``p3at fuse`` (text, ``--json`` and a
warning), the mission's fusion report and summary (``p3at demo --start-prior``), its live event line and the
recording's fusion status (session 47; fusion.Alignment.prior_backing)."""
from __future__ import annotations

import json

import numpy as np

from estimation.geometry import compose
from fusion.prior import StartPrior
from runtime.cli import main
from runtime.fusion_report import fuse_maps
from runtime.report import alignment_status, format_summary, fusion_event_line
from tests.fusion.test_fusion_prior import TRUE_POSE, twin_pair

LAB = np.array([1.0, 2.0, 0.3])       # map 1's robot in the lab


def _files(tmp_path, common: int, twins: int, seed: int = 0):
    m1, m2 = twin_pair(seed, common=common, twins=twins)
    paths = [tmp_path / "a.npz", tmp_path / "b.npz"]
    m1.save(paths[0])
    m2.save(paths[1])
    return [str(p) for p in paths]


def _starts(pose=TRUE_POSE) -> list[str]:
    start2 = compose(LAB, pose)
    return ["--start-pose", "0=" + ",".join(f"{v:.6f}" for v in LAB), "--start-pose",
            "1=" + ",".join(f"{v:.6f}" for v in start2), "--start-sigma", "1,0.3"]


def test_p3at_fuse_says_a_half_turn_was_settled_by_the_prior(tmp_path, capsys):
    files = _files(tmp_path, common=30, twins=24)          # ambiguous without a prior
    out = str(tmp_path / "merged.npz")
    assert main(["fuse", *files, "--out", out, *_starts()]) == 0          # found: the prior is the user's word
    text, err = capsys.readouterr()
    assert "    found with the prior: the maps alone are ambiguous (rival " in text
    assert "warning: map 1 -> map 0 rests on the start prior: the maps alone are ambiguous (rival " in err
    assert "if the prior is wrong, so is this alignment" in err
    assert main(["fuse", *files, "--out", out, "--json", *_starts()]) == 0
    a = json.loads(capsys.readouterr().out)["alignments"][0]
    assert a["found"] and a["rests_on_prior"].startswith("found with the prior: the maps alone are ambiguous")
    st = a["statistics"]
    assert st["prior_backed"] is True and st["prior_decides"] == "ambiguous"
    assert st["without_prior_rival_supports"] >= 20 and st["without_prior_rival_outside"] is True
    assert st["without_prior_required_supports"] > a["supports_count"]


def test_p3at_fuse_does_not_flag_a_pair_its_maps_decide(tmp_path, capsys):
    files = _files(tmp_path, common=40, twins=0, seed=3)   # unambiguous; the prior agrees
    out = str(tmp_path / "merged.npz")
    assert main(["fuse", *files, "--out", out, "--json", *_starts()]) == 0
    report, err = capsys.readouterr()
    a = json.loads(report)["alignments"][0]
    assert a["found"] and a["prior"] is not None
    assert a["rests_on_prior"] is None and a["statistics"]["prior_backed"] is False
    assert "rests on the start prior" not in err


def test_the_mission_s_reports_say_it_and_a_pair_the_maps_decide_says_nothing():
    m1, m2 = twin_pair(0, common=30, twins=24)
    prior = {("robot1", "robot2"): StartPrior.from_sigmas(TRUE_POSE, 1.0, 0.3)}
    pair = fuse_maps({"robot1": m1, "robot2": m2}, priors=prior).pairs[0]
    assert pair.aligned and pair.prior_backed.startswith("found with the prior: the maps alone are ambiguous")
    p = pair.as_dict()
    summary = format_summary(_summary(p))
    assert "warning: robot2 -> robot1 rests on the start prior: the maps alone are ambiguous" in " ".join(
        summary.split())
    assert "**found with the prior**: the maps alone are ambiguous" in alignment_status(10.0, p)   # the recording
    assert fusion_event_line(10.0, p).endswith(", found with the prior: the maps alone are ambiguous")
    u1, u2 = twin_pair(3, common=40, twins=0)
    plain = fuse_maps({"robot1": u1, "robot2": u2}, priors=prior).pairs[0]
    assert plain.aligned and plain.prior and plain.prior_backed == ""
    q = plain.as_dict()
    assert "start prior" not in format_summary(_summary(q)) and "found with the prior" not in alignment_status(1, q)
    assert "found with the prior" not in fusion_event_line(1.0, q)


def test_a_map_placed_through_a_prior_backed_alignment_says_so():
    """Three maps: robot3's map (robot2's, seen again) is placed through robot2, whose alignment to robot1 only the
    prior decides."""
    m1, m2 = twin_pair(0, common=30, twins=24)
    rng = np.random.default_rng(7)
    m3 = type(m2)(m2.positions + rng.normal(0, 0.01, m2.positions.shape), m2.covariances, m2.descriptors,
                  robot="robot3")
    prior = {("robot1", "robot2"): StartPrior.from_sigmas(TRUE_POSE, 1.0, 0.3)}
    pairs = {p.other: p for p in fuse_maps({"robot1": m1, "robot2": m2, "robot3": m3}, priors=prior).pairs}
    assert pairs["robot2"].aligned and pairs["robot2"].prior_backed.startswith("found with the prior")
    assert pairs["robot3"].aligned
    assert pairs["robot3"].prior_backed.startswith("found with the prior: the maps alone are ambiguous")
    assert pairs["robot3"].prior_backed.endswith("(through robot2 -> robot1)")


def _summary(pair: dict) -> dict:
    return {"duration": 10.0, "camera": "virtual", "particles": 1, "seed": 0, "robots": {},
            "fusion": {"pairs": [pair], "merged_landmarks": 1}, "fusion_ms": 1.0}
