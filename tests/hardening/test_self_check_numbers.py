"""A map's self-check verdict and frame counts with numbers JSON can hold but `p3at fuse` cannot use
(session 23): Infinity, or an integer of hundreds of digits, is a malformed verdict (a one-line note, the map
fused), as NaN already was. Before, `threshold: Infinity` came out of `fuse --json` as `Infinity` (jq refuses it)."""
from __future__ import annotations

import json
import math

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from runtime.map_self_check import NUMBER_FIELDS, read_self_check
from tests.datasets.conftest import run_cli
from tests.hardening.test_map_metadata import _pair, _with_metadata

SOUND = {"version": 1, "lost": False, "alarms": [], "n_alarms": 0, "threshold": 11.5, "false_alarm_per_frame": 1e-5,
         "dispersion": 1.0, "statistic": 0.0, "max_statistic": 0.0, "max_statistic_t": None, "frames": 10,
         "frames_tested": 0, "predicted": 0, "redetected": 0, "expected": 0.0}


def _strict(text: str):
    def refuse(constant):
        raise ValueError(f"not strict JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


@given(field=st.sampled_from(NUMBER_FIELDS),
       value=st.one_of(st.floats(), st.integers(-(10 ** 400), 10 ** 400), st.booleans(), st.none(),
                       st.text(max_size=3)))
@example(field="threshold", value=math.inf)
@example(field="threshold", value=10 ** 400)
def test_a_verdict_is_finite_numbers_or_one_line(field, value) -> None:
    try:
        verdict = read_self_check({"self_check": dict(SOUND, **{field: value})})
    except ValueError as e:
        assert "\n" not in str(e) and field in str(e)
        return
    _strict(json.dumps(verdict))


@pytest.mark.parametrize("value", [math.inf, 10 ** 400])
def test_fuse_json_stays_strict_json(tmp_path, value) -> None:
    m1, m2 = _pair()
    m1.save(tmp_path / "robot1.npz")
    hostile = _with_metadata(tmp_path / "robot2.npz", m2, "self_check", dict(SOUND, threshold=value))
    status, out, err = run_cli("fuse", str(hostile), str(tmp_path / "robot1.npz"), "--out", str(tmp_path / "o.npz"),
                               "--json")
    assert status == 0, err
    assert "self_check.threshold must be a finite number" in err and err.count("\n") == 1, err
    assert _strict(out)["maps"][0]["self_check"] is None


@given(value=st.one_of(st.integers(-(10 ** 400), 10 ** 400), st.floats(), st.booleans()))
@example(value=10 ** 400)
@example(value=(1 << 63) - 1)
def test_frame_counts_are_int64_or_one_line(value) -> None:
    """`slam_frames` counts of 400 digits: starved() raised OverflowError, `p3at fuse` exit 70."""
    from runtime.slam_frames import read_frame_counts, starved

    counts = {"received": value, "processed": 0, "dropped": value, "without_odometry": 0}
    try:
        read = read_frame_counts({"slam_frames": counts})
    except ValueError as e:
        assert "\n" not in str(e)
        return
    starved(read)


def test_fuse_with_huge_frame_counts_notes_them(tmp_path) -> None:
    m1, m2 = _pair()
    m1.save(tmp_path / "robot1.npz")
    counts = {"received": 10 ** 400, "processed": 0, "dropped": 10 ** 400, "without_odometry": 0}
    hostile = _with_metadata(tmp_path / "robot2.npz", m2, "slam_frames", counts)
    status, _, err = run_cli("fuse", str(tmp_path / "robot1.npz"), str(hostile), "--out", str(tmp_path / "o.npz"))
    assert status == 0 and "slam_frames.received must be a whole number >= 0 below 2^63" in err, err
    assert err.count("\n") == 1
