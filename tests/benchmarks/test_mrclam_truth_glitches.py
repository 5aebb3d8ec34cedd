"""benchmarks.mrclam_truth_glitches: the Vicon glitch rows found, and the cleaned copy of a data set folder."""
from __future__ import annotations

import gzip

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.mrclam_truth_glitches import census, glitch_rows, main, read_truth_lines
from estimation.geometry import wrap_angle
from estimation.odometry_response import fast_truth_steps
from tests.datasets.conftest import MRCLAM2


def _turning(n: int = 400, rate: float = 1.2, start: float = 2.5, dt: float = 0.02) -> np.ndarray:
    """A robot turning on the spot at ``rate`` rad/s through ±π, as Vicon writes it (wrapped)."""
    t = np.arange(n) * dt
    return np.column_stack([t, 1.0 + 0.1 * t, np.full(n, -2.0), wrap_angle(start + rate * t)])


def _wrap_glitch(truth: np.ndarray, at: int, count: int) -> np.ndarray:
    """``count`` rows from ``at`` replaced by a linear interpolation of the heading ACROSS the wrap (not wrap-aware),
    between the rows on either side: what MRCLAM's Vicon rows at ±π look like."""
    out = truth.copy()
    a, b = out[at - 1, 3], out[at + count, 3]
    for k in range(count):
        out[at + k, 3] = a + (k + 1) / (count + 1) * (b - a)
    return out


def _crossing(truth: np.ndarray) -> int:
    return int(np.flatnonzero(np.abs(np.diff(truth[:, 3])) > np.pi)[0]) + 1


def test_a_smooth_turn_through_the_wrap_has_no_glitch():
    truth = _turning()
    assert not fast_truth_steps(truth).any()
    assert len(glitch_rows(truth)) == 0


@settings(max_examples=40, deadline=None)
@given(count=st.integers(1, 3), rate=st.floats(-1.5, 1.5).filter(lambda r: abs(r) > 0.05),
       shift=st.integers(-1, 1))
def test_rows_interpolated_across_the_wrap_are_found_and_nothing_else(count, rate, shift):
    truth = _turning(rate=rate, start=2.9 if rate > 0 else -2.9)
    at = _crossing(truth) + shift
    bad = _wrap_glitch(truth, at, count)
    found = glitch_rows(bad)
    changed = np.flatnonzero(np.abs(wrap_angle(bad[:, 3] - truth[:, 3])) > 0.05)
    assert set(changed) <= set(found)
    assert set(found) <= set(range(at - 1, at + count + 1))          # at most one good neighbour taken with them
    keep = np.setdiff1d(np.arange(len(bad)), found)
    assert not fast_truth_steps(bad[keep]).any()


def test_a_position_jump_is_found():
    truth = _turning(rate=0.3)
    truth[100, 1] += 0.5
    assert list(glitch_rows(truth)) == [100]


def test_the_census_counts_an_episode_at_the_wrap():
    truth = _wrap_glitch(_turning(), _crossing(_turning()), 2)
    c = census(truth)
    assert (c["dropped"], c["episodes"], c["at_the_wrap"], c["fast_steps_left"]) == (2, 1, 2, 0)


def test_the_cleaned_copy_deletes_only_the_glitch_rows(tmp_path):
    src, out = tmp_path / "set", tmp_path / "clean"
    src.mkdir()
    truth = _wrap_glitch(_turning(), _crossing(_turning()), 1)
    text = "# header\n" + "".join(f"{t:.2f} {x:.4f} {y:.4f} {th:.5f}\n" for t, x, y, th in truth)
    with gzip.open(src / "Robot1_Groundtruth.dat.gz", "wt") as f:
        f.write(text)
    (src / "Robot1_Odometry.dat").write_text("0 0 0\n")
    assert main(["--data", str(src), "--robots", "1", "--clean", str(out)]) == 0
    lines, _, rows = read_truth_lines(out / "Robot1_Groundtruth.dat.gz")
    original = text.encode().split(b"\n")
    assert len(rows) == len(truth) - 1 and not fast_truth_steps(rows).any()
    [row] = glitch_rows(truth)
    assert lines == original[:row + 1] + original[row + 2:]             # the header and the rest byte-identical
    assert (out / "Robot1_Odometry.dat").read_text() == "0 0 0\n"
    assert main(["--data", str(src), "--robots", "1", "--clean", str(src)]) == 2


def test_the_cli_refuses_a_robot_number_that_is_not_positive(capsys):
    with pytest.raises(SystemExit):
        main(["--robots", "0"])
    assert "--robots" in capsys.readouterr().err


def test_mrclam_robot_1s_glitches_all_sit_at_the_wrap():
    found = [MRCLAM2 / name for name in ("Robot1_Groundtruth.dat.gz", "Robot1_Groundtruth.dat")
             if (MRCLAM2 / name).is_file()]
    if not found:
        pytest.skip(f"MRCLAM data set 2 not found in {MRCLAM2.resolve()} (../shared/data/mrclam, see its README)")
    c = census(read_truth_lines(found[0])[2])
    assert c["fast_steps"] == 47 and c["dropped"] == 27 and c["episodes"] == 16
    assert c["at_the_wrap"] == c["dropped"] and c["fast_steps_left"] == 0
