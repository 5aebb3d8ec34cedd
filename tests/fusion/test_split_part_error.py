"""A split map's part made after its gap does not share its map's start (fusion/split.py): the reports (the mission's
and fleet node's ``fuse_maps``, its summary, ``--json``, live line and viewer text, ``p3at review``, and ``p3at fuse``)
never score it against the true start poses, say so in words, and carry the evidence of the alignment that placed it
(session 26, E). Its 1σ is its own alignment's, said so, not the start-frame 1σ, which claims the map's start the gap
broke (session 27, D: the demo printed 0.563 m / 0.108 rad beside the part's own 0.082 m / 0.0155 rad).

Found on ``p3at demo --seed 0 --odometry exact``: robot 2 lost its frame at 13.8 s, only the part after the gap
aligned, and the demo printed "found, error 0.309 m / 0.2504 rad" (the map's loss, not the alignment's error) with
``required_supports: 0`` and no P(chance). Here the maps are benchmarks/fusion_sim.py's building pair with robot 2's
part after the gap kicked by ``KICK`` (tests/fusion/test_fusion_split.py), so the start-pose error of that part
would be the kick: about 1 m / 0.3 rad.
"""
from __future__ import annotations

import json

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion import true_relative_pose
from fusion.alignment import alignment_error_xy_theta
from fusion.split import fuse_checked, split_checks
from runtime.fusion_report import fuse_maps, sigmas
from runtime.report import alignment_status, alignment_text, format_summary, fusion_event_line
from tests.fusion.test_fusion_split import KICK, _pair, _verdict

AFTER = "the part after robot2's gap at t≈60.0 s does not share robot2's start"
OWN = "of the part's own alignment, none against the start frames"


def _summary(report) -> dict:
    return {"robots": {}, "camera": "x", "particles": 1, "seed": 0, "duration": 1.0, "fusion": report.as_dict()}


def _as_fuse_maps_fuses(m1, m2):
    """fuse_checked of the two maps as ``fuse_maps`` runs it (the flagged map checked by fusion.split.split_checks,
    each draw from the maps it aligns, since session 51; the parts fused with their own): the fusion whose placement
    and evidence the pair reports."""
    return fuse_checked([m1, m2], checks=split_checks([m1, m2]))


def _after_only(sim):
    """Maps 1 and 2 where robot 2's part made before its gap (2 landmarks) is too small to align: only the kicked
    part after the gap aligns, and is merged under its own alignment."""
    m1, m2, _, _ = _pair(sim, KICK, first_id=2)
    return m1, m2


def test_a_part_after_the_gap_is_not_scored_against_the_start_and_says_why(sim):
    m1, m2 = _after_only(sim)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    assert pair.aligned and pair.split_decision == "after" and pair.aligned_part == "after"
    # the decision and the placement are the fusion's own (unchanged): the pose of the part after the gap
    checked = _as_fuse_maps_fuses(m1, m2)
    after = checked.sources.index((1, "after"))
    np.testing.assert_array_equal([pair.tx, pair.ty, pair.theta], checked.fusion.poses[after])
    # scored against robot 2's start, that placement is off by the kick: that figure is the map's loss, not printed
    lost_xy, lost_theta = alignment_error_xy_theta(checked.fusion.poses[after], true_relative_pose(m1, m2))
    assert lost_xy > 0.5 and lost_theta > 0.2
    assert pair.error_xy is None and pair.error_theta is None
    assert pair.error_not_comparable == AFTER
    line = fusion_event_line(137.0, pair)
    assert line == (f"fusion at t=137s: robot2 -> robot1 ({pair.supports} supports, {pair.common} common), "
                    f"error against the truth not comparable: {AFTER}")
    text = alignment_text(pair.as_dict())
    assert f"error against the truth not comparable: {AFTER}" in text and "error against the truth 0" not in text
    summary = format_summary(_summary(fuse_maps({"robot1": m1, "robot2": m2})))
    row = next(s for s in summary.splitlines() if s.startswith("robot2 -> robot1  "))
    assert row.split()[-4:] == ["-", "-", "-", "-"]     # no start-frame 1σ, no error
    assert (f"robot2 -> robot1: 1σ {pair.sigma_xy:.3f} m / {pair.sigma_theta:.4f} rad {OWN}; error against the truth "
            f"not comparable: {AFTER}") in " ".join(s.strip() for s in summary.splitlines())


def test_a_part_after_the_gap_carries_its_own_evidence(sim):
    """The pair's needed supports, P(chance) and 1σ are those of the alignment that placed the part (in the demo they
    were 0 / null / null beside 'found')."""
    m1, m2 = _after_only(sim)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    checked = _as_fuse_maps_fuses(m1, m2)
    (edge,) = checked.fusion.alignments.values()
    assert edge.found
    st_ = edge.statistics
    assert pair.supports == len(edge.supports) and pair.required_supports == st_.required_supports > 0
    assert pair.supports >= pair.required_supports
    assert pair.false_alarm_probability == st_.false_alarm_probability < 1e-6 and not pair.low_confidence
    assert (pair.second_best_supports, pair.self_repeat_supports) == (st_.second_best_supports,
                                                                      st_.self_repeat_supports)
    text = alignment_text(pair.as_dict())
    assert f"{pair.supports} supports ({pair.required_supports} needed, P(chance) " in text and "; 1σ " in text


def test_a_part_after_the_gap_shows_its_own_alignments_1_sigma_not_the_broken_start_claim(sim):
    """The 1σ beside the part is its own alignment's (the fusion's covariance of its placement), said so; the
    start-frame 1σ, a claim about robot 2's start that the gap broke (here 10x the own one), is shown nowhere: not in
    the pair (``--json``), the summary's columns, review's or the viewer's text."""
    m1, m2 = _after_only(sim)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    checked = _as_fuse_maps_fuses(m1, m2)
    after = checked.sources.index((1, "after"))
    own, claim = sigmas(checked.fusion.covariances[after]), sigmas(checked.fusion.start_covariances[after])
    assert claim[0] > 3 * own[0] and claim[1] > 3 * own[1]
    assert (pair.sigma_xy, pair.sigma_theta) == own > (0, 0)
    assert pair.start_sigma_xy is None and pair.start_sigma_theta is None
    assert pair.start_sigma_not_comparable == AFTER
    recorded = json.loads(json.dumps(pair.as_dict()))           # as --json and the recording carry it
    assert recorded["start_sigma_xy"] is None and recorded["start_sigma_not_comparable"] == AFTER
    clause = f"1σ {own[0]:.3f} m / {own[1]:.4f} rad {OWN}; error against the truth not comparable: {AFTER}"
    for text in (alignment_text(recorded), alignment_text(recorded, missing="?"), alignment_status(137.0, recorded)):
        assert clause in text and f"{claim[0]:.3f}" not in text


def test_a_part_before_the_gap_keeps_its_start_frame_1_sigma(sim):
    m1, m2, _, _ = _pair(sim, KICK)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    assert pair.aligned_part == "before" and pair.start_sigma_xy > 0 and pair.start_sigma_not_comparable == ""
    text = alignment_text(pair.as_dict())
    assert f"; 1σ {pair.start_sigma_xy:.3f} m / {pair.start_sigma_theta:.4f} rad; error against the truth" in text
    assert OWN not in text


def test_the_part_before_the_gap_is_still_scored_with_its_evidence(sim):
    """Parts that disagree: the pair reports the part made before the gap, which holds robot 2's start: its error is
    given (small: the kick moved only the other part) and so is its evidence."""
    m1, m2, _, _ = _pair(sim, KICK)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    assert pair.split_decision == "parts" and pair.aligned_part == "before" and pair.error_not_comparable == ""
    assert pair.error_xy < 0.1 and pair.error_theta < 0.02
    assert pair.required_supports > 0 and pair.false_alarm_probability < 1e-6 and pair.start_sigma_xy > 0


def test_a_reference_map_with_nothing_before_its_gap_gives_no_start_error(sim, tmp_path, capsys):
    """The reference's part after its gap is the fused frame when nothing was made before it: no pair is scored
    against the reference's start then, in the mission's report or by p3at fuse."""
    from runtime.cli import main

    m1, m2, _, _ = _pair(sim)
    del m2.metadata["self_check"]
    m1.ids = np.arange(len(m1))
    m1.metadata["self_check"] = _verdict(0)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    why = "the part after robot1's gap at t≈60.0 s does not share robot1's start"
    assert pair.aligned and pair.aligned_part is None and pair.error_xy is None and pair.error_not_comparable == why
    assert pair.start_sigma_xy is None and pair.start_sigma_not_comparable == why
    m1.save(tmp_path / "r1.npz")
    m2.save(tmp_path / "r2.npz")
    assert main(["fuse", str(tmp_path / "r1.npz"), str(tmp_path / "r2.npz"), "--out", str(tmp_path / "m.npz"),
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    placed = report["maps"][1]
    assert placed["pose_in_reference"] is not None and placed.get("error_xy") is None
    assert placed["error_not_comparable"] == why
    assert report["alignments"][0]["error_xy"] is None and "robot1's gap" in report["alignments"][0][
        "error_not_comparable"]


def test_maps_without_truth_give_no_reason_for_a_missing_error(sim):
    m1, m2 = _after_only(sim)
    for m in (m1, m2):
        m.metadata.pop("true_start_pose", None)
    (pair,) = fuse_maps({"robot1": m1, "robot2": m2}).pairs
    assert pair.aligned and pair.aligned_part == "after"
    assert pair.error_xy is None and pair.error_not_comparable == ""
    assert fusion_event_line(1.0, pair).endswith(f"({pair.supports} supports, {pair.common} common)")
    # no truth to compare with, but the start-frame 1σ is still a claim about a start the part does not share
    assert pair.start_sigma_xy is None and pair.start_sigma_not_comparable == AFTER
    assert f"1σ {pair.sigma_xy:.3f} m / {pair.sigma_theta:.4f} rad {OWN} ({AFTER})" in alignment_text(pair.as_dict())


def test_p3at_fuse_gives_no_start_error_for_an_alignment_resting_on_a_part_after_the_gap(sim, tmp_path, capsys):
    from runtime.cli import main

    m1, m2 = _after_only(sim)
    m1.save(tmp_path / "r1.npz")
    m2.save(tmp_path / "r2.npz")
    args = ["fuse", str(tmp_path / "r1.npz"), str(tmp_path / "r2.npz"), "--out", str(tmp_path / "m.npz")]
    assert main(args + ["--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    (entry,) = report["alignments"]
    assert entry["found"] and not entry["used"] and entry["true_pose"] is not None
    assert entry["error"] is None and entry["error_xy"] is None and entry["error_theta"] is None
    count = entry["supports_count"]
    why = f"{count} of its {count} supports in robot2's map lie in the part after robot2's gap at t≈60.0 s, which " \
          "does not share robot2's start"
    assert entry["error_not_comparable"] == why
    # its start-frame 1σ claims robot2's start: not given; its own precision is
    assert entry["covariance"] is not None and entry["start_covariance"] is None
    assert entry["start_covariance_not_comparable"] == why
    assert main(args) == 0
    out = capsys.readouterr().out
    assert f"error vs true start poses: not comparable: {count} of its {count} supports" in out
    assert "error vs true start poses: error xy" not in out
    assert "    precision (1σ): " in out and "against the true start frames (1σ" not in out
    assert f"against the true start frames: no 1σ (the precision above is of the part's own alignment): {why}" in out


def test_p3at_fuse_still_scores_an_alignment_of_a_map_used_whole(sim, tmp_path, capsys):
    from runtime.cli import main

    m1, m2, _, _ = _pair(sim)     # flagged, but its parts agree: the map is used whole
    m1.save(tmp_path / "r1.npz")
    m2.save(tmp_path / "r2.npz")
    assert main(["fuse", str(tmp_path / "r1.npz"), str(tmp_path / "r2.npz"), "--out", str(tmp_path / "m.npz"),
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    (entry,) = report["alignments"]
    assert report["maps"][1]["split"]["decision"] == "whole"
    assert entry["error_xy"] < 0.1 and "error_not_comparable" not in entry
    assert entry["start_covariance"] is not None and "start_covariance_not_comparable" not in entry


def test_a_part_without_its_own_covariance_shows_no_1_sigma_and_says_why():
    """Recorded without the alignment's own covariance (no sigma_xy): no 1σ at all, the reason said once."""
    pair = {"reference": "robot1", "other": "robot2", "aligned": True, "tx": 1.0, "ty": 2.0, "theta": 0.1,
            "supports": 40, "common": 40, "start_sigma_xy": None, "start_sigma_not_comparable": AFTER}
    assert f"; no 1σ against the start frames ({AFTER})" in alignment_text(pair)
    text = alignment_text({**pair, "error_xy": None, "error_not_comparable": AFTER})
    assert f"; no 1σ against the start frames; error against the truth not comparable: {AFTER}" in text
    assert text.count(AFTER) == 1


@settings(max_examples=100, deadline=None)
@given(why=st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=30),
                     st.lists(st.text(max_size=3), max_size=2)),
       sigma_why=st.one_of(st.none(), st.integers(), st.text(max_size=30), st.just(AFTER)),
       sigma=st.one_of(st.none(), st.floats(), st.text(max_size=3)))
def test_any_recorded_reason_is_worded_in_one_line(why, sigma_why, sigma):
    """A recording written by another version (or anything) may hold any JSON in the fields: one line, no
    exception, in the review's and viewer's text and the summary."""
    pair = {"reference": "robot1", "other": "robot2", "aligned": True, "tx": 1.0, "ty": 2.0, "theta": 0.1,
            "supports": 40, "common": 40, "error_xy": None, "error_theta": None, "error_not_comparable": why,
            "start_sigma_not_comparable": sigma_why, "sigma_xy": sigma, "sigma_theta": sigma}
    for text in (alignment_text(pair), alignment_text(pair, markdown=True), fusion_event_line(3.0, pair)):
        assert isinstance(text, str) and "\n" not in text and "\r" not in text
    summary = format_summary({"robots": {}, "camera": "x", "particles": 1, "seed": 0, "duration": 1.0,
                              "fusion": {"pairs": [dict(pair, supports=40)], "merged_landmarks": 1}})
    assert "robot2 -> robot1" in summary
