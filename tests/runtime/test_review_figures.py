"""``p3at review FILE.rrd`` says what a recording's alignment rests on (supports against the number needed, P(chance),
its 1 σ, a low-confidence flag) as the demo's table does, names a pair not aligned the same way, and leads a data set
run's recording (``p3at slam dataset ... --rerun``) with the run's own figures."""
from __future__ import annotations

import pytest

from runtime.cli import main
from runtime.rerun_log import MissionLog
from runtime.rerun_sink import open_recording

ALIGNED = {"reference": "robot1", "other": "robot2", "aligned": True, "tx": 4.992, "ty": 0.024, "theta": 3.1382,
           "supports": 39, "required_supports": 33, "false_alarm_probability": 6.9e-11, "common": 39,
           "start_sigma_xy": 0.457, "start_sigma_theta": 0.0632, "error_xy": 0.025, "error_theta": 0.0034}


def _review(tmp_path, capsys, name: str, log_it) -> list[str]:
    rrd = tmp_path / f"{name}.rrd"
    log = MissionLog(open_recording(str(rrd)), ["robot1", "robot2"], blueprint=False)
    log_it(log)
    log.close()
    assert main(["review", str(rrd), "--no-export"]) == 0
    return capsys.readouterr().out.splitlines()


def test_an_alignment_is_reviewed_with_what_it_rests_on(tmp_path, capsys):
    out = _review(tmp_path, capsys, "aligned", lambda log: log.log_alignment(144.0, "robot1", "robot2", ALIGNED))
    assert ("  alignment robot2 -> robot1: aligned: tx 4.992 m, ty 0.024 m, θ 3.1382 rad; 39 supports (33 needed, "
            "P(chance) 6.9e-11), 39 common landmarks; 1σ 0.457 m / 0.0632 rad; error against the truth 0.025 m / "
            "0.0034 rad") in out
    low = _review(tmp_path, capsys, "low", lambda log: log.log_alignment(
        144.0, "robot1", "robot2", {**ALIGNED, "low_confidence": True}))
    assert any(line.endswith("LOW CONFIDENCE: check it before use") for line in low)


def test_a_pair_not_aligned_is_named_as_the_demo_names_it(tmp_path, capsys):
    out = _review(tmp_path, capsys, "none", lambda log: log.log_alignment(
        60.0, "robot1", "robot2", {"reference": "robot1", "other": "robot2", "aligned": False, "supports": 9,
                                   "note": "only 9 supports"}))
    assert "  alignment robot2 -> robot1: not aligned: only 9 supports" in out


# the states a pair can be in after a fusion, as the mission records them (PairResult.as_dict())
STATES = {
    "aligned": ALIGNED,
    "low confidence": {**ALIGNED, "low_confidence": True},
    "too few supports": {"reference": "robot1", "other": "robot2", "aligned": False, "supports": 9,
                         "required_supports": 34, "false_alarm_probability": 1.0, "self_repeat_supports": 22,
                         "second_best_supports": 7, "note": "ambiguous: one map repeats itself under a distinct "
                                                             "transform with 22 supports"},
    "candidate": {"reference": "robot1", "other": "robot2", "aligned": False, "supports": 26,
                  "note": "candidate: 26 supports at (0.15 m, -0.01 m, -0.001 rad); no earlier fusion of these maps "
                          "found it"},
    "split": {**ALIGNED, "split_decision": "before", "self_check": "robot2 flagged itself at 80 s ..."},
    "another version's": {"reference": "robot1", "other": "robot2", "aligned": True, "tx": 1.0, "ty": 2.0,
                          "supports": 3},
}


@pytest.mark.parametrize("state", sorted(STATES))
def test_review_says_an_alignment_in_the_words_of_the_viewers_fusion_status(tmp_path, capsys, state):
    """Session 26 (C): review and the viewer's fusion status worded one state two ways ('none (…)' beside
    '**not aligned**: 9 supports, 34 needed …'; a candidate as 'none' beside 'not yet aligned'); now one function
    (runtime.report.alignment_text) words both, the viewer's in Markdown."""
    from runtime.rerun_style import FUSION_STATUS

    from .rerun_helpers import entity_rows

    out = _review(tmp_path, capsys, "s", lambda log: log.log_alignment(30.0, "robot1", "robot2", STATES[state]))
    (line,) = [line for line in out if line.startswith("  alignment ")]
    shown = str(entity_rows(tmp_path / "s.rrd", FUSION_STATUS)[-1]["TextDocument:text"][0])
    head = "**robot2 → robot1** (fusion at t = 30 s): "
    assert shown.startswith(head)
    viewer = shown.removeprefix(head).replace("**low confidence**", "LOW CONFIDENCE").replace("**", "")
    assert line.removeprefix("  alignment robot2 -> robot1: ") == viewer.replace(" - ", " ? ")


def test_a_data_set_runs_recording_leads_with_the_runs_figures(tmp_path, capsys):
    figures = {"ate_m": 0.0297, "dead_reckoning_ate_m": 3.404, "landmarks": 15, "true_landmarks": 15,
               "landmark_error_median_m": 0.0219, "pose_nees_median": 1.46, "pose_nees_within_chi2_95": 0.9635,
               "smoothed": True, "robot": "robot2"}
    out = _review(tmp_path, capsys, "dataset", lambda log: log.log_summary(figures))
    assert ("  run: ATE 0.030 m (dead reckoning 3.404 m), landmarks 15 for 15 true, median error 0.022 m, pose NEES "
            "median 1.5 (96 % below χ²₃(95 %)); smoothed over the whole log") in out
    assert "  no alignment in this recording" not in out
    assert not [line for line in out if "WARNING" in line]


def test_a_data_set_runs_warnings_are_printed_on_printable_lines_and_at_most_twenty(tmp_path, capsys):
    figures = {"ate_m": 0.283, "robot": "robot1",
               "warnings": ["the map's frame rests on single sightings: …", "a \x1b[2Jhostile\nline", 7]}
    out = _review(tmp_path, capsys, "warned", lambda log: log.log_summary(figures))
    assert [line for line in out if "WARNING" in line] == [
        "  WARNING: the map's frame rests on single sightings: …", "  WARNING: a \\x1b[2Jhostile\\x0aline"]
    many = {"ate_m": 0.283, "warnings": [f"warning {k}" for k in range(25)]}
    out = _review(tmp_path, capsys, "many", lambda log: log.log_summary(many))
    shown = [line for line in out if "WARNING" in line]
    assert shown[0] == "  WARNING: warning 0" and shown[19] == "  WARNING: warning 19"
    assert shown[20] == "  WARNING: … and 5 more in the recording" and len(shown) == 21


def test_a_part_after_its_gap_is_reviewed_with_its_own_1_sigma_as_the_viewer_shows_it(tmp_path, capsys):
    """Session 27 (D): a split map's part made after its gap, as the mission records it (``p3at demo --seed 0
    --odometry exact``): review and the viewer's fusion status give its own alignment's 1σ, said so, and not the
    start-frame 1σ (null in the record), with the reason once."""
    from runtime.rerun_style import FUSION_STATUS

    from .rerun_helpers import entity_rows

    why = "the part after robot2's gap at t≈13.8 s does not share robot2's start"
    part = {**ALIGNED, "tx": 5.129, "ty": 0.281, "theta": -2.8912, "supports": 50, "required_supports": 30,
            "false_alarm_probability": 3.3e-21, "common": 50, "sigma_xy": 0.082, "sigma_theta": 0.0155,
            "start_sigma_xy": None, "start_sigma_theta": None, "start_sigma_not_comparable": why, "error_xy": None,
            "error_theta": None, "error_not_comparable": why, "split_decision": "after", "aligned_part": "after",
            "self_check": "robot2 flagged itself at t≈13.8 s: ..."}
    out = _review(tmp_path, capsys, "after", lambda log: log.log_alignment(137.0, "robot1", "robot2", part))
    (line,) = [line for line in out if line.startswith("  alignment ")]
    assert ("50 common landmarks; 1σ 0.082 m / 0.0155 rad of the part's own alignment, none against the start "
            f"frames; error against the truth not comparable: {why}; robot2 flagged itself") in line
    shown = str(entity_rows(tmp_path / "after.rrd", FUSION_STATUS)[-1]["TextDocument:text"][0])
    assert line.removeprefix("  alignment robot2 -> robot1: ") == shown.split("): ", 1)[1].replace("**", "")
